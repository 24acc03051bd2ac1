"""The ``rovslam`` command. Parses, calls the library, prints. Heavy imports stay inside commands.

Exit codes: 0 success; 2 bad input, an unusable run or an unusable output place (one line on
stderr naming the problem, never a traceback); 128 + the signal number when a run is stopped
by SIGINT (130), SIGTERM (143) or SIGHUP (129), its files complete; 1 an internal error (a
bug: one line, the traceback with ``ROVSLAM_TRACEBACK=1``). Messages are printed as plain
text, never interpreted as rich markup (``[camera]`` stays as it is).

This module holds the typer ``app``, the global options (``--version``) and :func:`main`. Each
command lives in a module of its own and registers itself on ``app`` when imported:

- ``simulate``: ``simulate``
- ``run``: ``run``, ``import``, ``topics`` (their input options: ``inputs``)
- ``evaluate``: ``eval``
- ``batch``: ``batch``
- ``demo``: ``demo``
- ``report``: ``report``, ``mosaic``
- ``config``: ``config``
- ``smooth``: ``smooth``
- ``navigate``: ``navigate``
- ``live``: ``live`` (on the vehicle: the camera stream and MAVLink)
- ``sitl``: ``sitl`` (the simulator as a vehicle on the network)

What they share: ``errors`` (``guard``: every error one line on stderr and an exit code;
``fail``; ``error_line``), ``display`` (progress bars, tables) and ``checks`` (output files,
``-c`` configuration files, ``--seq`` folders).

A new command ``NAME`` is a module ``rovslam/cli/NAME.py``::

    import typer

    from rovslam.cli import app
    from rovslam.cli.errors import guard

    @app.command()
    @guard
    def NAME(quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display.")) -> None:
        "What it does, in one line: rovslam --help shows it."
        from rovslam.runner import run_sequence  # heavy imports here, so --help stays fast

plus its name in ``COMMAND_MODULES`` at the end of this module: ``rovslam --help`` lists the
commands in that order. A command that reads a video, an image folder or
a bag takes their options with ``@with_inputs`` (``rovslam.cli.inputs``) below ``@guard``.

The modules with commands do not use ``from __future__ import annotations``: typer reads every
parameter's annotation at each start-up, and a string annotation is compiled again each time
(``rovslam --help`` and every command spent about 4 ms of CPU on it).
"""

import importlib
import sys

import typer

from rovslam.cli.errors import error_line


def _plain_help() -> None:
    """Help text as a user reads it: no ``<bool>`` after a flag (it takes no value) and an argument's name
    in capitals in the usage line (``SEQUENCE``, ``[OUT]``) instead of typer's ``{sequence}``.

    typer (pinned in pyproject.toml) decides both in two small methods; they are replaced here once.
    """
    from typer.core import TyperArgument, TyperOption

    shown = TyperOption.display_type_rich

    def display_type_rich(self, ctx):  # a flag takes no value: no type to show
        return None if self.is_flag and not self.count else shown(self, ctx)

    def usage_name(self) -> str:
        name = self.display_name_raw.upper() + ("..." if self.nargs != 1 else "")
        return name if self.required else f"[{name}]"

    TyperOption.display_type_rich = display_type_rich  # type: ignore[method-assign]
    TyperArgument._usage_display_name = usage_name  # type: ignore[method-assign]


_plain_help()

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Vision-based SLAM for ROVs: laser altimeter, optical-correlation speed, EKF landmark map.",
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    """``--version``: print it and exit before anything else is parsed."""
    if value:
        from rovslam import __version__

        typer.echo(f"rovslam {__version__}")
        raise typer.Exit()


@app.callback()
def _main_options(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Vision-based SLAM for ROVs: laser altimeter, optical-correlation speed, EKF landmark map."""


def main() -> None:
    """The console script: like ``app()``, but a command-line usage error is one line too."""
    from typer.main import get_command

    try:
        code = get_command(app).main(prog_name="rovslam", standalone_mode=False)
    except typer.TyperException as exc:
        fmt = getattr(exc, "format_message", None)
        ctx = getattr(exc, "ctx", None)
        hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        error_line(f"{fmt() if fmt else exc}{hint}")
        code = getattr(exc, "exit_code", 2)
    except typer.Abort:
        code = 130
    sys.exit(code if isinstance(code, int) else 0)


# The commands: importing a module registers its commands on `app`; --help lists them in this order.
COMMAND_MODULES = (
    "simulate",
    "run",
    "evaluate",
    "batch",
    "demo",
    "report",
    "config",
    "smooth",
    "navigate",
    "live",
    "sitl",
)
for _module in COMMAND_MODULES:
    importlib.import_module(f"rovslam.cli.{_module}")
