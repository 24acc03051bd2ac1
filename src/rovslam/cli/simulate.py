"""``rovslam simulate``: a simulated dive written as a sequence folder with exact ground truth."""

import math
from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.display import ProgressBar
from rovslam.cli.errors import guard


@app.command()
@guard
def simulate(
    scenario: str = typer.Option("portofino-short", help="Scenario preset (see --list)."),
    out: Path = typer.Option(Path("sim-seq"), "--out", "-o", help="Sequence folder to write."),
    frames: int | None = typer.Option(None, help="Number of frames (default: the scenario's)."),
    seed: int = typer.Option(0, help="Random seed; the same seed writes byte-identical files."),
    image_format: str | None = typer.Option(None, "--format", help="png or jpg (default: the scenario's)."),
    texture: Path | None = typer.Option(
        None, help="Seabed photo/orthomosaic to use instead of the procedural texture."
    ),
    texture_mm_per_px: float | None = typer.Option(None, help="Scale of --texture (millimetres per pixel)."),
    calibration_errors: bool = typer.Option(
        False,
        "--calibration-errors",
        help="Draw the seed's lasting sensor errors (compass deviation 0.5 deg, laser-rig baseline 0.76 %, sonar offset "
        "1 cm, one sigma) and record them in sequence.toml; default: exact sensors.",
    ),
    relief_scale: float = typer.Option(
        1.0,
        "--relief-scale",
        help="Multiply every height of the scenario's relief (0: a flat seabed; 2: twice as deep).",
    ),
    list_scenarios: bool = typer.Option(False, "--list", help="List the scenarios and exit."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Simulate an ROV dive over a seabed and write a sequence folder with exact ground truth."""
    from rovslam.errors import SimulationError
    from rovslam.sim import SCENARIOS, CalibrationErrors
    from rovslam.sim import simulate as run_sim

    if list_scenarios:
        for name, sc in SCENARIOS.items():
            typer.echo(f"{name:18s} {sc.summary_line()}")
        return
    if image_format is not None and image_format not in ("png", "jpg"):
        raise SimulationError(f"--format must be png or jpg, got {image_format!r}")
    if frames is not None and frames <= 0:
        raise SimulationError(f"--frames must be a positive number of frames, got {frames}")
    with ProgressBar(quiet, "simulating") as bar:
        summary = run_sim(
            scenario,
            out,
            frames=frames,
            seed=seed,
            image_format=image_format,
            texture_path=texture,
            texture_mm_per_px=texture_mm_per_px,
            progress=bar,
            calibration=CalibrationErrors() if calibration_errors else None,
            relief_scale=relief_scale,
        )
    typer.echo(f"wrote {out} ({_describe(summary)})")
    d = summary.calibration
    if d is not None:
        typer.echo(
            f"calibration errors of seed {seed}: compass {math.degrees(d.compass_deviation_rad):+.2f} deg, "
            f"laser rig {100 * d.laser_baseline_error:+.2f} %, sonar {100 * d.sonar_offset_m:+.2f} cm "
            "(sequence.toml [metadata])"
        )


def _describe(summary) -> str:
    """What the simulation wrote, for its last line: frames and wall time."""
    frames = getattr(summary, "frames", None)
    wall = getattr(summary, "wall_s", None)
    parts = []
    if frames is not None:
        parts.append(f"{frames} frames")
    if wall:
        parts.append(f"{wall:.1f} s")
    return ", ".join(parts) or "done"
