"""``rovslam config``: the default configuration (the paper's values) as a TOML file to edit."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.checks import check_output_file
from rovslam.cli.errors import guard


@app.command(name="config")
@guard
def config_cmd(
    out: Path = typer.Argument(..., help="TOML file to write with every default."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the file if it exists."),
) -> None:
    """Write the default configuration (the paper's values) to a TOML file to edit."""
    import tomli_w

    from rovslam.config import RunConfig, to_dict
    from rovslam.errors import OutputError
    from rovslam.io.results import atomic_write_text

    check_output_file(out, "the configuration file")
    if out.exists() and not overwrite:
        raise OutputError(f"{out}: exists; add --overwrite to replace it, or give another name.")
    atomic_write_text(out, tomli_w.dumps(to_dict(RunConfig())))
    typer.echo(f"wrote {out}")
