"""The seabed map's landmarks: their templates and records (:mod:`~rovslam.mapping.landmarks`) and
which of a frame's matches the filter believes (:mod:`~rovslam.mapping.association`)."""
