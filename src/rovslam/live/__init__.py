"""``rovslam live``: the vehicle's camera stream and autopilot telemetry in, a position with covariance out.

* :mod:`rovslam.live.stream`: the video stream (PyAV), a decoder thread keeping the newest frame.
* :mod:`rovslam.live.telemetry`: the autopilot's attitude and altitude by time, interpolated to a frame.
* :mod:`rovslam.live.messages`: the MAVLink messages of a frame's estimate (pure numbers).
* :mod:`rovslam.live.mavlink`: the MAVLink link (pymavlink): heartbeat, telemetry in, messages out.
* :mod:`rovslam.live.session`: the live run, :func:`rovslam.runner.run_sequence` fed by the stream.
* :mod:`rovslam.live.command`: the ``rovslam live`` command.

Importing this package imports nothing heavy (no PyAV, no pymavlink).
"""
