"""Benchmark of the smoothing back end (GTSAM iSAM2), one core.

Run: ``python benchmarks/bench_smoother.py`` (``--quick`` for small sizes, ``--no-trial`` to
skip the full-trial run). Prints:

* per-frame cost of :meth:`Isam2Smoother.add_frame` (median and mean over ``--repeats`` timed
  frames) once the graph holds 1,000 / 10,000 poses and 100 / 1,000 landmarks, beside the
  baseline measured in the same run: the EKF's predict + updates on the same frames
  (:class:`rovslam.slam.EkfSlam`, O(landmarks^2) per update);
* the cost of the final :meth:`Isam2Smoother.smoothed` at those sizes (median of 3 calls);
* the full portofino trial (13,275 frames, the paper's 0.7 m grid flown for 44 min, ~1
  landmark observation per frame): the whole incremental pass and the final smoothing,
  against the issue's budget (under two minutes online on one core, under 30 s final);
* why every factor is a compiled GTSAM factor: one optimiser iteration over 20 landmark
  factors written as ``gtsam.CustomFactor`` (Python) against ``gtsam_unstable.DeltaFactor``
  in a graph of N variables (GTSAM hands the Python callback a copy of all N values).

Streams are synthetic (``tests/synth.py``: a true track, a landmark field, seeded noise):
for the size grid, a cross-hatched square survey whose landmarks lie along the first
``poses`` frames, each frame observing the nearest one within 20 cm (revisits on every pass).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path


def _parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, nargs="+", default=[1000, 10000], help="graph sizes (poses)")
    ap.add_argument("--landmarks", type=int, nargs="+", default=[100, 1000], help="graph sizes (landmarks)")
    ap.add_argument("--repeats", type=int, default=50, help="timed frames per size")
    ap.add_argument("--quick", action="store_true", help="poses 500 2000, landmarks 50 200, no trial")
    ap.add_argument("--no-trial", action="store_true", help="skip the full portofino trial")
    ap.add_argument("--trial-frames", type=int, default=13275, help="frames of the trial run")
    return ap.parse_args()


ARGS = _parse() if __name__ == "__main__" else None
if ARGS is not None:  # one core: BLAS reads its thread count when numpy is first imported
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from synth import SurveyNoise, crosshatch_track, landmark_field, survey_measurements  # noqa: E402

from rovslam.camera import rot2  # noqa: E402
from rovslam.config import SlamConfig  # noqa: E402
from rovslam.slam import EkfSlam, MotionInput, observation_noise_px2, observe_mn  # noqa: E402
from rovslam.slam.measurements import FrameMeasurements, LandmarkMeasurement  # noqa: E402
from rovslam.slam.smoother import Isam2Smoother, SmootherConfig  # noqa: E402

NOISE = SurveyNoise()
Z_M, F_PX, DT_S = NOISE.altitude_m, NOISE.focal_px, 0.2
# Seconds budgets of the issue for the full trial.
ONLINE_BUDGET_S, FINAL_BUDGET_S = 120.0, 30.0


def sized_stream(n_frames: int, poses: int, landmarks: int, seed: int = 0) -> list[FrameMeasurements]:
    """Records of ``n_frames`` frames over a cross-hatched square sized so that ``poses`` frames
    fly one cycle; ``landmarks`` landmarks lie (1-5 cm off) on the track of the first ``poses``
    frames; each frame observes the nearest landmark within 20 cm (initialising it if new)."""
    rng = np.random.default_rng(seed)
    side = max(0.35, float(np.sqrt(poses * 0.02 / 11.4)))  # a cycle is ~11.4 side^2 metres long
    xy, psi = crosshatch_track(n_frames, side_m=side, lane_m=side / 4)
    at = np.linspace(0, poses - 1, landmarks).astype(int)
    lms = xy[at] + rng.uniform(0.01, 0.05, (landmarks, 2)) * rng.choice([-1, 1], (landmarks, 2))
    compass = psi + rng.normal(0.0, NOISE.compass_sigma_rad, n_frames)
    seen: set[int] = set()
    frames = []
    for k in range(n_frames):
        d = np.hypot(*(lms - xy[k]).T)
        near = np.flatnonzero(d < 0.2)
        fresh = [i for i in near[np.argsort(d[near])] if i not in seen]
        obs = ()
        if len(near):  # the nearest new landmark is initialised, else the nearest one tracked
            i = fresh[0] if fresh else int(near[np.argmin(d[near])])
            mn = observe_mn(lms[i], xy[k], psi[k], Z_M, F_PX)[0] + rng.normal(0.0, 0.5, 2)
            obs = (
                LandmarkMeasurement(int(i), "track" if i in seen else "init", mn, observation_noise_px2(mn, 0.5, Z_M)),
            )
            seen.add(int(i))
        v = np.zeros(2) if k == 0 else rot2(psi[k - 1]).T @ (xy[k] - xy[k - 1]) / DT_S  # (1) inverted
        frames.append(
            FrameMeasurements(
                index=k,
                t_s=k * DT_S,
                dt_s=DT_S if k else 0.0,
                speed_mps=v + (rng.normal(0, 2e-3, 2) if k else 0.0),
                speed_cov_mps2=np.eye(2) * 4e-6 if k else np.zeros((2, 2)),
                speed_ok=k > 0,
                heading_rad=float(psi[k]),
                heading_sigma_rad=NOISE.compass_sigma_rad,
                compass_rad=float(compass[k]),
                compass_sigma_rad=NOISE.compass_sigma_rad,
                heading_step_rad=0.0 if k else np.nan,
                heading_step_sigma_rad=NOISE.step_sigma_rad if k else np.nan,
                altitude_m=Z_M,
                altitude_sigma_m=0.0,
                focal_px=F_PX,
                landmarks=obs,
            )
        )
    return _dense_ids(frames)


def _dense_ids(frames: list[FrameMeasurements]) -> list[FrameMeasurements]:
    """Landmark ids 0, 1, ... in order of initialisation (as the pipeline numbers them)."""
    import dataclasses

    new_id: dict[int, int] = {}
    out = []
    for f in frames:
        obs = []
        for ob in f.landmarks:
            if ob.landmark_id not in new_id:
                new_id[ob.landmark_id] = len(new_id)
            obs.append(dataclasses.replace(ob, landmark_id=new_id[ob.landmark_id]))
        out.append(dataclasses.replace(f, landmarks=tuple(obs)))
    return out


class EkfRunner:
    """The baseline: the EKF fed the same records (predict, then update / augment)."""

    def __init__(self):
        self.ekf = EkfSlam(SlamConfig(), initial_capacity=64)
        self.prev: FrameMeasurements | None = None

    def add_frame(self, f: FrameMeasurements) -> None:
        ekf = self.ekf
        if self.prev is not None:
            ekf.predict(
                MotionInput(
                    f.speed_mps[0], f.speed_mps[1], f.speed_cov_mps2, self.prev.heading_rad, f.dt_s, f.heading_sigma_rad
                )
            )
        for ob in f.landmarks:
            if ob.kind == "init":
                ekf.augment(ob.mn_px, f.heading_rad, f.altitude_m, f.focal_px)
            else:
                ekf.update(ob.landmark_id, ob.mn_px, f.heading_rad, f.altitude_m, f.focal_px)
        self.prev = f


def time_frames(backend, frames) -> list[float]:
    out = []
    for f in frames:
        t0 = time.perf_counter()
        backend.add_frame(f)
        out.append(time.perf_counter() - t0)
    return out


def bench_size(poses: int, landmarks: int, repeats: int) -> dict:
    frames = sized_stream(poses + repeats, poses, landmarks)
    sm, ekf = Isam2Smoother(SmootherConfig()), EkfRunner()
    t0 = time.perf_counter()
    for f in frames[:poses]:
        sm.add_frame(f)
    build_s = time.perf_counter() - t0
    for f in frames[:poses]:
        ekf.add_frame(f)
    n_poses, n_landmarks = sm.n_poses, sm.n_landmarks
    ts = time_frames(sm, frames[poses:])
    te = time_frames(ekf, frames[poses:])
    finals = []
    for _ in range(3):
        t0 = time.perf_counter()
        sm.smoothed()
        finals.append(time.perf_counter() - t0)
    return dict(
        poses=n_poses,
        landmarks=n_landmarks,
        build_s=build_s,
        median_ms=1e3 * statistics.median(ts),
        mean_ms=1e3 * statistics.fmean(ts),
        ekf_ms=1e3 * statistics.median(te),
        final_s=statistics.median(finals),
    )


def bench_trial(n_frames: int) -> dict:
    xy, psi = crosshatch_track(n_frames)
    sv = survey_measurements(0, xy, psi, landmark_field(0, xy), NOISE, spacing_m=0.15, max_observations=1)
    sm = Isam2Smoother(SmootherConfig())
    per = np.empty(n_frames)
    t0 = time.perf_counter()
    for k, f in enumerate(sv.frames):
        a = time.perf_counter()
        sm.add_frame(f)
        per[k] = time.perf_counter() - a
    online_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = sm.smoothed()
    final_s = time.perf_counter() - t0
    ate_mm = 1e3 * float(np.sqrt(np.mean(np.sum((res.xy_m - sv.xy_m) ** 2, axis=1))))
    quint = [1e3 * float(np.median(c)) for c in np.array_split(per, 5)]
    return dict(
        frames=n_frames,
        landmarks=sm.n_landmarks,
        observations=int(res.landmark_observations.sum()),
        online_s=online_s,
        final_s=final_s,
        ate_mm=ate_mm,
        quintile_median_ms=quint,
        mean_ms=1e3 * float(per.mean()),
        max_ms=1e3 * float(per.max()),
    )


def bench_custom_factor(n_values: int, n_factors: int = 20) -> tuple[float, float]:
    """Seconds of one Gauss-Newton iteration over a graph of ``n_values`` poses with ``n_factors``
    landmark factors as Python CustomFactors vs compiled DeltaFactors (medians of 3)."""
    import gtsam
    import gtsam_unstable

    def landmark_error(this, values, jacobians):
        pose, lm = values.atPose2(this.keys()[0]), values.atPoint2(this.keys()[1])
        if jacobians is not None:
            jacobians[0] = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
            jacobians[1] = np.eye(2)
        return pose.transformTo(lm)

    values = gtsam.Values()
    graph0 = gtsam.NonlinearFactorGraph()
    prior = gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
    for i in range(n_values):
        values.insert(i, gtsam.Pose2(0.01 * i, 0.0, 0.0))
        graph0.add(gtsam.PriorFactorPose2(i, gtsam.Pose2(0.01 * i, 0.0, 0.0), prior))
    lm_key = gtsam.symbol("l", 0)
    values.insert(lm_key, np.zeros(2))
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1e-3)
    out = []
    for custom in (True, False):
        graph = gtsam.NonlinearFactorGraph(graph0)
        for i in range(n_factors):
            if custom:
                graph.add(gtsam.CustomFactor(noise, [i, lm_key], landmark_error))
            else:
                graph.add(gtsam_unstable.DeltaFactor(i, lm_key, np.zeros(2), noise))
        times = []
        for _ in range(3):
            params = gtsam.GaussNewtonParams()
            params.setMaxIterations(1)
            opt = gtsam.GaussNewtonOptimizer(graph, values, params)
            t0 = time.perf_counter()
            opt.iterate()
            times.append(time.perf_counter() - t0)
        out.append(statistics.median(times))
    return out[0], out[1]


def main() -> None:
    args = ARGS
    if args.quick:
        args.poses, args.landmarks, args.no_trial = [500, 2000], [50, 200], True
    print("per-frame cost of add_frame (one iSAM2 update + the newest pose's marginal), one core")
    print(
        f"{'poses':>7} {'landmarks':>9} | {'iSAM2 median':>12} {'mean':>8} | {'EKF median':>10} | "
        f"{'smoothed()':>10} | {'build':>7}"
    )
    for p in args.poses:
        for m in args.landmarks:
            r = bench_size(p, m, args.repeats)
            print(
                f"{r['poses']:>7} {r['landmarks']:>9} | {r['median_ms']:>9.2f} ms {r['mean_ms']:>5.2f} ms | "
                f"{r['ekf_ms']:>7.3f} ms | {r['final_s']:>8.2f} s | {r['build_s']:>5.1f} s",
                flush=True,
            )
    print("\nGauss-Newton iteration, 20 landmark factors in a graph of N poses: CustomFactor (Python) vs DeltaFactor")
    for n in (1000, 10000):
        c, d = bench_custom_factor(n)
        print(
            f"  N = {n:>6}: CustomFactor {1e3 * c:8.1f} ms, DeltaFactor {1e3 * d:7.1f} ms: "
            f"{1e3 * (c - d) / 40:.3f} ms more per Python evaluation (20 linearisations + 20 errors)"
        )
    if not args.no_trial:
        r = bench_trial(args.trial_frames)
        print(f"\nfull trial: {r['frames']} frames, {r['landmarks']} landmarks, {r['observations']} observations")
        print(
            f"  incremental pass {r['online_s']:.1f} s (budget {ONLINE_BUDGET_S:.0f} s: "
            f"{'met' if r['online_s'] < ONLINE_BUDGET_S else 'NOT met'}), mean {r['mean_ms']:.2f} ms/frame, "
            f"max {r['max_ms']:.0f} ms"
        )
        print("  median ms/frame per fifth of the dive: " + ", ".join(f"{q:.2f}" for q in r["quintile_median_ms"]))
        print(
            f"  final smoothing {r['final_s']:.1f} s (budget {FINAL_BUDGET_S:.0f} s: "
            f"{'met' if r['final_s'] < FINAL_BUDGET_S else 'NOT met'}); smoothed ATE {r['ate_mm']:.2f} mm"
        )


if __name__ == "__main__":
    main()
