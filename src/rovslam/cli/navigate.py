"""``rovslam navigate``: the closed loop in the simulator, steered to points of interest by the online estimate."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.checks import load_config
from rovslam.cli.display import ProgressBar, quiet_native_logs
from rovslam.cli.errors import error_line, fail, guard


@app.command()
@guard
def navigate(
    scenario: str = typer.Option(
        ..., "--scenario", help="Simulator preset (rovslam simulate --list), e.g. portofino-relief."
    ),
    poi: Path = typer.Option(
        ..., "--poi", help="Points of interest, CSV: name,x_m,y_m[,hold_s] or name,landmark_id[,hold_s]."
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the results (new or empty, or see --overwrite)."),
    estimator: str = typer.Option("slam", help="What the controller steers by: slam or dead-reckoning."),
    survey_s: float = typer.Option(
        0.0, "--survey-s", help="Fly a lawnmower survey this long first, to build the map (s)."
    ),
    hold_s: float = typer.Option(
        10.0, "--hold-s", help="Station keeping at each point, unless its hold_s says otherwise (s)."
    ),
    approach_gain_per_s: float | None = typer.Option(
        None,
        "--approach-gain-per-s",
        help="How hard the vehicle is steered back to a point: the desired speed per metre off it "
        "(default 0.2; 0.3 holds closer and arrives sooner on a rough sea, see docs/navigation.md).",
    ),
    seed: int = typer.Option(0, help="Random seed of the seabed, the current and the sensors."),
    config: Path | None = typer.Option(None, "--config", "-c", help="TOML configuration of the pipeline."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the results of an earlier run in --out."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """Closed loop in the simulator: survey, then visit the points of interest steered by the online estimate.

    Writes the usual results plus arrivals.csv (true and estimated error at each point),
    navigation.csv, groundtruth.csv and navigation.png. Ctrl-C keeps what is written.
    """
    from rovslam.config import RunConfig
    from rovslam.errors import InvalidArgumentError
    from rovslam.io.poi import read_poi_csv
    from rovslam.nav.estimate import check_estimator
    from rovslam.nav.guidance import guidance_config
    from rovslam.navigate import navigate as fly
    from rovslam.runner import StopRequest
    from rovslam.sim import SCENARIOS

    if scenario not in SCENARIOS:
        raise InvalidArgumentError(f"--scenario: unknown preset {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
    check_estimator(estimator)
    for name, v in (("--survey-s", survey_s), ("--hold-s", hold_s)):
        if not (v >= 0 and v != float("inf")):
            raise InvalidArgumentError(f"{name} must be a number of seconds >= 0, got {v}")
    if seed < 0:
        raise InvalidArgumentError(f"--seed must be a whole number >= 0, got {seed}")
    guidance = guidance_config(hold_s, approach_gain_per_s)
    pois = read_poi_csv(poi)
    cfg = load_config(config) if config is not None else RunConfig()
    rate = SCENARIOS[scenario].frame_rate_hz
    quiet_native_logs()
    with StopRequest() as late, ProgressBar(quiet, f"navigate ({estimator})", extra=True) as bar:
        callbacks = (
            {}
            if bar is None
            else {
                "on_start": lambda s: bar(0, int(s * rate)),
                "on_step": lambda st, done: bar(
                    st.k + 1,
                    None,
                    landmarks=st.nav.result.n_landmarks,
                    tokens=f"{st.nav.result.tokens_tracked}  points {done}/{len(pois)}",
                ),
            }
        )
        summary = fly(
            scenario,
            pois,
            out,
            estimator,
            survey_s,
            hold_s,
            seed,
            cfg,
            guidance=guidance,
            overwrite=overwrite,
            **callbacks,  # type: ignore[arg-type]
        )
        late.ignore_after = summary.status == "interrupted"
    rows = summary.arrivals
    errs = [r["true_err_m"] for r in rows if r["reached"]]
    msg = (
        f"{summary.frames} frames, {summary.landmarks} landmarks, {len(errs)}/{len(pois)} points reached"
        + (
            f", true arrival error mean {1e3 * sum(errs) / len(errs):.1f} mm, worst {1e3 * max(errs):.1f} mm"
            if errs
            else ""
        )
        + f" -> {out}"
    )
    if summary.status == "interrupted":
        error_line(f"{msg}; every file written is complete and readable", f"rovslam: stopped by {summary.signal}: ")
        raise typer.Exit(summary.exit_code)
    typer.echo(msg)
    if summary.status != "complete":
        fail(f"not every point was reached (see {out / 'arrivals.csv'})")
