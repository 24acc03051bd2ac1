"""``rovslam eval``: a run against the ground truth, the figures as JSON and as tables."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.checks import check_output_file, check_sequence_of_run
from rovslam.cli.display import print_eval
from rovslam.cli.errors import guard


@app.command(name="eval")
@guard
def eval_cmd(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    groundtruth: Path = typer.Option(..., "--groundtruth", "-g", help="groundtruth.csv of the sequence."),
    json_out: Path | None = typer.Option(None, "--json", help="Where to write the figures (default OUT/eval.json)."),
    sequence: Path | None = typer.Option(
        None, "--sequence", "-s", help="The sequence that was run: adds the frame-to-frame phase-correlation baseline."
    ),
) -> None:
    """Compare a run with the ground truth: ATE, drift, dead reckoning, 2-sigma coverage, NEES, error jumps, Table 1."""
    if json_out is not None:
        check_output_file(json_out, "--json")
    path = json_out or (results / "eval.json")
    check_sequence_of_run(results, sequence, "--sequence")
    write_evaluation(results, groundtruth, path, sequence)
    typer.echo(f"wrote {path}")


def write_evaluation(results: Path, groundtruth: Path, json_path: Path, sequence: Path | None = None) -> None:
    """Evaluate a run against the truth, write the figures as JSON and print them as tables."""
    from rovslam.eval import evaluate_run
    from rovslam.io.results import atomic_write_text, json_text

    figures = evaluate_run(results, groundtruth, sequence)
    atomic_write_text(
        json_path, json_text(figures.to_dict()) + "\n"
    )  # strict JSON: a figure that cannot be computed is null
    print_eval(figures)
