"""The laser-triangulation optical-correlation sensor over time: what the paper's LTOC sensor
measures from frame to frame, beyond one image's vision (:mod:`rovslam.vision`).

* :mod:`~rovslam.sensor.altitude`: the image depth filtered over time;
* :mod:`~rovslam.sensor.odometry`: surge, sway and turn from the speed tokens, and the held speed;
* :mod:`~rovslam.sensor.heading`: the heading inputs (compass and the tokens' turn);
* :mod:`~rovslam.sensor.shutter`: a rolling shutter's rows moved to the frame's time;
* :mod:`~rovslam.sensor.sunlight`: sunlight caustics watched and taken out.
"""
