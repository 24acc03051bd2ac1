"""``rovslam eval``: a run against the ground truth and / or the feature reference, the figures as JSON and as tables."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.checks import check_output_file, check_sequence_of_run
from rovslam.cli.display import print_eval
from rovslam.cli.errors import fail, guard

REFERENCES = ("features",)


@app.command(name="eval")
@guard
def eval_cmd(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    groundtruth: Path | None = typer.Option(None, "--groundtruth", "-g", help="groundtruth.csv of the sequence."),
    json_out: Path | None = typer.Option(None, "--json", help="Where to write the figures (default OUT/eval.json)."),
    sequence: Path | None = typer.Option(
        None, "--sequence", "-s", help="The sequence that was run: adds the frame-to-frame phase-correlation baseline."
    ),
    reference: str | None = typer.Option(
        None,
        "--reference",
        help="features: compare every frame pair's token motion with the feature motion of the run's input "
        "(no ground truth needed).",
    ),
) -> None:
    """Compare a run with the ground truth (ATE, drift, dead reckoning, 2-sigma coverage, NEES, error jumps,
    Table 1) and / or, with no ground truth, its frame pairs' motions with the feature reference."""
    if reference is not None and reference not in REFERENCES:
        fail(f"--reference {reference}: unknown reference; the one there is: {', '.join(REFERENCES)}.")
    if groundtruth is None and reference is None:
        fail(f"eval {results}: nothing to compare with; give --groundtruth groundtruth.csv or --reference features.")
    if json_out is not None:
        check_output_file(json_out, "--json")
    path = json_out or (results / "eval.json")
    if groundtruth is None:
        if sequence is not None:
            fail("--sequence adds a baseline to the ground-truth evaluation; give --groundtruth with it.")
        write_feature_reference(results, path)
    else:
        check_sequence_of_run(results, sequence, "--sequence")
        write_evaluation(results, groundtruth, path, sequence, features=reference == "features")
    typer.echo(f"wrote {path}")


def write_evaluation(
    results: Path, groundtruth: Path, json_path: Path, sequence: Path | None = None, features: bool = False
) -> None:
    """Evaluate a run against the truth (and the feature reference), write the figures as JSON, print them."""
    from rovslam.eval import evaluate_run
    from rovslam.io.results import atomic_write_text, json_text

    figures = evaluate_run(results, groundtruth, sequence)
    data = figures.to_dict()
    if features:
        data["feature_reference"] = _feature_reference(results)
    atomic_write_text(json_path, json_text(data) + "\n")  # strict JSON: a figure that cannot be computed is null
    print_eval(figures)
    if features:
        _print_feature_reference(data["feature_reference"])


def write_feature_reference(results: Path, json_path: Path) -> None:
    """Compare a run's frame pairs with the feature reference, write ``feature_reference`` to JSON, print it."""
    from rovslam.io.results import atomic_write_text, json_text

    data = {"feature_reference": _feature_reference(results)}
    atomic_write_text(json_path, json_text(data) + "\n")
    _print_feature_reference(data["feature_reference"])


def _feature_reference(results: Path) -> dict:
    from rovslam.eval.feature_reference import feature_reference

    return feature_reference(results).to_dict()


def _print_feature_reference(figures: dict) -> None:
    share = figures["agree_share"]
    typer.echo(
        f"feature reference: {figures['compared']} of {figures['pairs']} frame pairs compared; "
        + (f"{100 * share:.1f} % agree (within 10 % or 2 sigma)" if share == share else "none could be compared")
    )
    for row in figures["worst"]:
        typer.echo(
            f"  frames {row['frame_prev']} -> {row['frame']}: tokens ({row['token_px'][0]:.1f}, {row['token_px'][1]:.1f})"
            f" px, features ({row['feature_px'][0]:.1f}, {row['feature_px'][1]:.1f}) px, "
            f"{100 * row['relative']:.0f} %, {row['mahalanobis']:.1f} sigma"
            + (" (held speed)" if row["held"] else "")
            + ("" if row["agrees"] else "  DISAGREE")
        )
