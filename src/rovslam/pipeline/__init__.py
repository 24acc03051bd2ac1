"""The per-frame loop of the paper (section 3.4), one :class:`FrameResult` per frame.

* :mod:`rovslam.pipeline.loop`: :class:`SlamPipeline`, the loop's steps (docs/architecture.md,
  "The loop") and the back end fed with each frame's measurements;
* :mod:`rovslam.pipeline.records`: the per-frame records (:class:`FrameResult`,
  :class:`Observation`, :class:`TrackedLandmark`), the measurements the back ends read, the
  reported covariance, the map's rows and what ``summary.json`` says of the run;
* the steps' collaborators: :mod:`~rovslam.pipeline.depth` (step 1's depth over time),
  :mod:`~rovslam.pipeline.image` (the tracking image, the sunlight watch), :mod:`~rovslam.pipeline.search`
  (step 3), :mod:`~rovslam.pipeline.speed` (step 5), :mod:`~rovslam.pipeline.prediction` and
  :mod:`~rovslam.pipeline.update` (step 6), :mod:`~rovslam.pipeline.geometry` (the image geometry).
"""

from rovslam.mapping.landmarks import LandmarkRecord
from rovslam.pipeline.loop import SlamPipeline
from rovslam.pipeline.records import FrameResult, Observation, TrackedLandmark

__all__ = ["FrameResult", "LandmarkRecord", "Observation", "SlamPipeline", "TrackedLandmark"]
