"""The input options of a video, an image folder or a ROS bag (camera file, navigation log, times, topics).

``@with_inputs`` gives a command all of them as one checked ``inputs: InputOptions`` argument
(`run`, `import`); in ``--help`` they are grouped under their own two panels.
"""

from __future__ import annotations

from pathlib import Path

import typer

from rovslam.cli.display import plain_help

_IN = "Inputs: video, image folder, navigation log (README, 'Your own dive')"
_BAG = "Inputs: ROS bags (ROS 1 .bag, ROS 2 sqlite3 or MCAP folder)"
_CAMERA_OPT = typer.Option(
    None,
    "--camera",
    help=plain_help(
        "Camera file of a video, image folder or bag: [camera], optional "
        "[[laser]], [vehicle] altitude_m and [nav] (the columns of --nav)."
    ),
    rich_help_panel=_IN,
)
_NAV_OPT = typer.Option(
    None,
    "--nav",
    help="Navigation log (CSV): heading or a quaternion, roll, pitch, altitude by time, interpolated to each frame.",
    rich_help_panel=_IN,
)
_NAV_OFFSET_OPT = typer.Option(
    None,
    "--nav-time-offset",
    help=plain_help(
        "The navigation clock's time at the first frame (s): "
        "a row at time T belongs to the frame at T - S (overrides [nav] time_offset_s)."
    ),
    rich_help_panel=_IN,
)
_NAV_MAP_OPT = typer.Option(
    None,
    "--nav-map",
    help=plain_help(
        "KEY=VALUE of the [nav] table, e.g. time=ts, heading=hdg, "
        "angle_unit=deg, altitude=alt_m, quaternion=qx,qy,qz,qw (repeatable; overrides the camera file)."
    ),
    rich_help_panel=_IN,
)
_FPS_OPT = typer.Option(
    None, "--fps", help="Frame rate of a folder of images (frame k at k / F s).", rich_help_panel=_IN
)
_TIMES_OPT = typer.Option(
    None, "--times", help="CSV image,t_s giving the time of each image of a folder.", rich_help_panel=_IN
)
_IMAGE_TOPIC_OPT = typer.Option(
    None, "--image-topic", help="sensor_msgs/Image or CompressedImage topic.", rich_help_panel=_BAG
)
_HEADING_TOPIC_OPT = typer.Option(
    None, "--heading-topic", help="sensor_msgs/Imu, nav_msgs/Odometry or std_msgs/Float64 topic.", rich_help_panel=_BAG
)
_ALTITUDE_TOPIC_OPT = typer.Option(
    None, "--altitude-topic", help="sensor_msgs/Range or std_msgs/Float64 (m) topic.", rich_help_panel=_BAG
)
_ATTITUDE_TOPIC_OPT = typer.Option(
    None,
    "--attitude-topic",
    help="sensor_msgs/Imu or nav_msgs/Odometry topic for roll and pitch.",
    rich_help_panel=_BAG,
)
_CAMERA_INFO_OPT = typer.Option(
    None,
    "--camera-info-topic",
    help=plain_help("sensor_msgs/CameraInfo topic (replaces [camera]'s K and distortion)."),
    rich_help_panel=_BAG,
)
_HEADING_CONV_OPT = typer.Option(
    "enu", "--heading-convention", help="Orientation topics: enu (ROS, REP 103) or ned.", rich_help_panel=_BAG
)
_HEADING_DEG_OPT = typer.Option(
    False, "--heading-degrees", help="A std_msgs/Float64 heading topic is in degrees.", rich_help_panel=_BAG
)


_INPUT_PARAMS = {  # name -> (type, option): the input options of `run` and `import`
    "camera": (Path | None, _CAMERA_OPT),
    "nav": (Path | None, _NAV_OPT),
    "nav_time_offset": (float | None, _NAV_OFFSET_OPT),
    "nav_map": (list[str] | None, _NAV_MAP_OPT),
    "fps": (float | None, _FPS_OPT),
    "times": (Path | None, _TIMES_OPT),
    "image_topic": (str | None, _IMAGE_TOPIC_OPT),
    "heading_topic": (str | None, _HEADING_TOPIC_OPT),
    "altitude_topic": (str | None, _ALTITUDE_TOPIC_OPT),
    "attitude_topic": (str | None, _ATTITUDE_TOPIC_OPT),
    "camera_info_topic": (str | None, _CAMERA_INFO_OPT),
    "heading_convention": (str, _HEADING_CONV_OPT),
    "heading_degrees": (bool, _HEADING_DEG_OPT),
}


def with_inputs(fn):
    """Give a command the input options of `run` (camera file, navigation log, times, topics) as one
    ``inputs: InputOptions`` argument, checked; the command's own signature names it last."""
    import functools
    import inspect

    sig = inspect.signature(fn)
    own = [prm for prm in sig.parameters.values() if prm.name != "inputs"]
    added = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=opt, annotation=kind)
        for name, (kind, opt) in _INPUT_PARAMS.items()
    ]

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        values = {name: kwargs.pop(name) for name in _INPUT_PARAMS}
        return fn(*args, inputs=_input_options(**values), **kwargs)

    wrapper.__signature__ = sig.replace(parameters=[*own, *added])
    return wrapper


def _input_options(
    camera,
    nav,
    nav_time_offset,
    nav_map,
    fps,
    times,
    image_topic,
    heading_topic,
    altitude_topic,
    attitude_topic,
    camera_info_topic,
    heading_convention,
    heading_degrees,
):
    """The input options as one :class:`rovslam.io.source.InputOptions`, checked."""
    from rovslam.errors import InvalidArgumentError
    from rovslam.io.source import InputOptions

    pairs = []
    for item in nav_map or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InvalidArgumentError(f"--nav-map takes KEY=VALUE (a key of the [nav] table), got {item!r}")
        pairs.append((key.strip(), value))
    if heading_convention not in ("enu", "ned"):
        raise InvalidArgumentError(f"--heading-convention must be enu or ned, got {heading_convention!r}")
    if nav_time_offset is not None and nav_time_offset != nav_time_offset:
        raise InvalidArgumentError("--nav-time-offset must be a number of seconds, got nan")
    return InputOptions(
        camera_file=camera,
        nav_file=nav,
        nav_map=tuple(pairs),
        nav_time_offset_s=nav_time_offset,
        fps=fps,
        times_file=times,
        image_topic=image_topic,
        heading_topic=heading_topic,
        altitude_topic=altitude_topic,
        attitude_topic=attitude_topic,
        camera_info_topic=camera_info_topic,
        heading_convention=heading_convention,
        heading_degrees=heading_degrees,
    )
