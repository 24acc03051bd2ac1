"""What a user sees when a command fails: one line on stderr and an exit code, never a traceback.

Every command is wrapped in :func:`guard`: a :class:`rovslam.errors.RovslamError` (bad input) and an
``OSError`` exit 2, a Ctrl-C 130, anything else (a bug) 1 with the traceback only under
``ROVSLAM_TRACEBACK=1``. :func:`fail` ends a command with a message; :func:`error_line` prints one.
"""

from __future__ import annotations

import os
import re
from typing import NoReturn

import typer


def error_line(message: str, prefix: str = "rovslam: error: ") -> None:
    """Print ``prefix`` + ``message`` on one line of stderr, the message as plain text (no markup)."""
    from rich.console import Console
    from rich.text import Text

    line = re.sub(r"\s*[\r\n]+\s*", " ", str(message)).strip()
    try:
        Console(stderr=True, highlight=False, soft_wrap=True).print(Text.assemble((prefix, "bold red"), line))
    except OSError:  # stderr gone (a closed terminal): nothing left to tell
        pass


def fail(message: str, code: int = 2) -> NoReturn:
    """End the command: ``message`` as the error line, exit ``code``."""
    error_line(message)
    raise typer.Exit(code)


def guard(fn):
    """Turn every error into one line on stderr and an exit code: 2 for bad input, 1 for a bug."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from rovslam.errors import RovslamError

        try:
            return fn(*args, **kwargs)
        except (typer.Exit, typer.Abort, typer.TyperException):
            raise
        except RovslamError as exc:
            fail(str(exc))
        except KeyboardInterrupt:
            fail("interrupted", 130)
        except OSError as exc:
            from rovslam.io.results import describe_os_error

            where = f"{exc.filename}: " if exc.filename else ""
            fail(f"{where}{describe_os_error(exc)}")
        except Exception as exc:
            if os.environ.get("ROVSLAM_TRACEBACK"):
                raise
            fail(
                f"internal error ({type(exc).__name__}: {exc}). This is a bug: please report it with the command "
                "line; ROVSLAM_TRACEBACK=1 shows the traceback.",
                1,
            )

    return wrapper
