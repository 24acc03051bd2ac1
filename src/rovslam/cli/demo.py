"""``rovslam demo``: simulate the paper's trial, run SLAM, evaluate and write the report, in one go."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.display import ProgressBar, quiet_native_logs, slam_callbacks
from rovslam.cli.errors import fail, guard
from rovslam.cli.evaluate import write_evaluation


@app.command()
@guard
def demo(
    out: Path = typer.Option(Path("rovslam-demo"), "--out", "-o", help="Folder for everything the demo writes."),
    scenario: str = typer.Option("portofino-short", help="Scenario to simulate."),
    frames: int | None = typer.Option(None, help="Number of frames (default: the scenario's)."),
    seed: int = typer.Option(0, help="Simulation seed."),
    quiet: bool = typer.Option(False, "--quiet", "-q"),
) -> None:
    """Simulate the paper's trial, run SLAM, evaluate and write the report, in one go."""
    from rovslam.runner import StopRequest, run_sequence
    from rovslam.sim import simulate as run_sim
    from rovslam.viz.report import write_report

    seq, res = out / "sequence", out / "results"
    if _same_simulation(seq, scenario, frames, seed):
        typer.echo(f"reusing the simulated sequence in {seq}")
    else:
        if seq.exists():
            import shutil

            from rovslam.errors import OutputError

            if not _is_simulated_sequence(seq):
                raise OutputError(
                    f"{seq}: exists and is not a sequence rovslam simulated; give the demo another --out."
                )
            shutil.rmtree(seq)  # the demo's own folder, from another scenario or seed
        with ProgressBar(quiet, "simulating") as bar:
            run_sim(scenario, seq, frames=frames, seed=seed, progress=bar)
    quiet_native_logs()
    with StopRequest() as late, ProgressBar(quiet, "SLAM", extra=True) as bar:
        summary = run_sequence(seq, res, overwrite=True, **slam_callbacks(bar))
        late.ignore_after = summary.interrupted
    if summary.interrupted:
        fail(f"stopped by {summary.signal}; partial results are in {res}", summary.exit_code)
    write_evaluation(res, seq / "groundtruth.csv", res / "eval.json", seq)
    report = write_report(res, seq / "groundtruth.csv")
    typer.echo(f"{summary.frames} frames at {summary.fps:.0f} frames/s; results in {res}")
    typer.echo(f"report: {report}")
    typer.echo(
        "next: open the report in a browser; run your own dive with "
        "`rovslam run VIDEO --camera CAMERA.toml --nav NAV.csv --out OUT` (README, 'Your own dive'), "
        "or try it live with `rovslam sitl` and `rovslam live` (README, 'On the vehicle')."
    )


def _is_simulated_sequence(seq: Path) -> bool:
    """Whether ``seq`` is a sequence folder rovslam's simulator wrote (so the demo may replace it)."""
    import tomllib

    from rovslam.errors import parse_toml

    try:
        meta = parse_toml((seq / "sequence.toml").read_text(encoding="utf-8")).get("metadata", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return isinstance(meta, dict) and meta.get("generator") == "rovslam.sim"


def _same_simulation(seq: Path, scenario: str, frames: int | None, seed: int) -> bool:
    """Whether ``seq`` is a complete simulation of this scenario, length and seed (the demo reuses it)."""
    from rovslam.errors import RovslamError
    from rovslam.io.sequence import open_sequence

    if not (seq / "sequence.toml").is_file():
        return False
    try:
        s = open_sequence(seq)
    except RovslamError:
        return False
    from rovslam.sim import SCENARIOS

    if scenario not in SCENARIOS:
        return False
    want = frames if frames is not None else SCENARIOS[scenario].n_frames
    meta = s.info.metadata
    return meta.get("scenario") == scenario and meta.get("seed") == seed and len(s) == want == meta.get("frames")
