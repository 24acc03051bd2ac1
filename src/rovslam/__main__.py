"""The ``rovslam`` console script: :func:`rovslam.cli.main`, with a Ctrl-C during its start-up ending quietly.

``rovslam.cli`` imports typer, click and rich before its commands can turn a KeyboardInterrupt
into ``rovslam: error: interrupted``; a Ctrl-C in that first tenth of a second printed a
traceback. Here it exits with 130 (the shell's code for SIGINT) and prints nothing.

``rovslam --version`` alone is answered here, without importing the command line (typer and
rich take most of a start-up): the same line, in a fifth of the time.
"""

from __future__ import annotations

import sys


def main() -> None:
    if sys.argv[1:] == ["--version"]:
        from rovslam import __version__

        print(f"rovslam {__version__}")
        sys.exit(0)
    try:
        from rovslam.cli import main as cli_main
    except KeyboardInterrupt:
        sys.exit(130)
    cli_main()


if __name__ == "__main__":  # python -m rovslam
    main()
