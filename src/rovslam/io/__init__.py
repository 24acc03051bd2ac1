"""Input and output: sequence folders (format v1), result files."""

from rovslam.core import Frame, GroundTruth, SequenceInfo
from rovslam.io.sequence import (
    FrameRow,
    Sequence,
    SequenceWriter,
    open_sequence,
    read_groundtruth,
    read_image,
)

__all__ = [
    "Frame",
    "FrameRow",
    "GroundTruth",
    "Sequence",
    "SequenceInfo",
    "SequenceWriter",
    "open_sequence",
    "read_groundtruth",
    "read_image",
]
