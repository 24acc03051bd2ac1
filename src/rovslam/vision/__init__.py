"""Vision front-end: band-pass + local variance (Misu et al.), template extraction with
inhibition masks, normalised-correlation tracking, laser-triangulation altimeter.

Pure functions on NumPy arrays, with thin stateful wrappers (:class:`TokenTracker`,
:class:`LaserAltimeter`) only where state is real. Never imports slam, io or viz.
"""

from rovslam.vision.filters import bandpass, local_variance, template_channel
from rovslam.vision.laser import (
    AltitudeEstimate,
    LaserAltimeter,
    fuse_altitude,
    predict_spot_pixels,
    spot_altitude_sigmas,
    triangulate_points,
    triangulate_spots,
)
from rovslam.vision.spots import detect_laser_spots
from rovslam.vision.templates import (
    Template,
    extract_templates,
    inhibit_boxes,
    inhibition_mask,
    window_inhibited,
)
from rovslam.vision.tracking import (
    Match,
    TokenTracker,
    TokenTracks,
    global_shift,
    match_template,
)

__all__ = [
    "AltitudeEstimate",
    "LaserAltimeter",
    "Match",
    "Template",
    "TokenTracker",
    "TokenTracks",
    "bandpass",
    "detect_laser_spots",
    "extract_templates",
    "fuse_altitude",
    "global_shift",
    "inhibit_boxes",
    "inhibition_mask",
    "local_variance",
    "match_template",
    "predict_spot_pixels",
    "spot_altitude_sigmas",
    "template_channel",
    "triangulate_points",
    "triangulate_spots",
    "window_inhibited",
]
