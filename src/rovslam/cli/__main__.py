"""``python -m rovslam.cli``: the ``rovslam`` command."""

from rovslam.cli import main

if __name__ == "__main__":
    main()
