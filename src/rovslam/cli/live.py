"""``rovslam live``: registered here; its options and body are :func:`rovslam.live.command.live`
(typer only at import: the stream, pymavlink and the pipeline load when the command runs)."""

from rovslam.cli import app
from rovslam.cli.errors import guard
from rovslam.live.command import live

__all__ = ["live"]

app.command(name="live")(guard(live))
