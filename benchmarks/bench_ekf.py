"""Benchmark of the EKF-SLAM core: one predict + one update with N = 10, 100, 1000, 5000 landmarks.

Run: ``python benchmarks/bench_ekf.py`` (``--threads 2`` to let BLAS use both cores,
``--sizes 10 100`` for a quick run). Prints the median over repeats of:

* ``rovslam``: :meth:`EkfSlam.predict` + :meth:`EkfSlam.update` (O(N^2) rank-4 Joseph update);
* ``dense``: a baseline measured in the same run, the textbook full-matrix update
  ``(I - K H) P (I - K H)^T + K R K^T`` with dense H and K, O(N^3); skipped above
  ``--dense-max`` landmarks (its time is then extrapolated as N^3 and marked ``~``);
* the gate (5) over all landmarks plus the new-landmark test (6), and one augmentation (4).
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def _parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000, 5000], help="landmark counts")
    ap.add_argument("--repeats", type=int, default=50, help="timed predict+update cycles per size")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1: one core)")
    ap.add_argument("--dense-max", type=int, default=1000, help="largest N for the dense baseline")
    return ap.parse_args()


ARGS = _parse() if __name__ == "__main__" else None
if ARGS is not None:  # BLAS reads its thread count when numpy is first imported
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(ARGS.threads)

import numpy as np  # noqa: E402

from rovslam.camera import rot2  # noqa: E402
from rovslam.config import SlamConfig  # noqa: E402
from rovslam.slam import EkfSlam, MotionInput, observation_noise_px2  # noqa: E402

Z_M, F_PX, W_PX, H_PX, DT_S = 1.31, 1075.0, 360, 272, 0.2
Q = np.eye(2) * 0.002**2


def build(n_landmarks: int, seed: int = 0) -> EkfSlam:
    """A filter with N landmarks along a random walk (full cross-covariances).

    The capacity leaves room for a few more, so the timed augmentation is the ordinary O(N)
    one, not a capacity doubling (an O(N^2) copy that happens log2(N) times in a run).
    """
    rng = np.random.default_rng(seed)
    ekf = EkfSlam(SlamConfig(), initial_capacity=n_landmarks + 8)
    for _ in range(n_landmarks):
        psi = rng.uniform(-np.pi, np.pi)
        ekf.predict(MotionInput(0.1, 0.0, Q, psi, DT_S))
        ekf.augment(rng.uniform(-120, 120, 2), psi, Z_M, F_PX)
    return ekf


def dense_predict_update(x, p, k, mn, psi, r_m, u, v, q, dt):
    """Textbook EKF step with full matrices: F = I, dense H (2 x n), Joseph form."""
    n = len(x)
    r = rot2(psi)
    g = np.zeros((n, 2))
    g[0:2] = r * dt
    x = x.copy()
    x[0:2] += r @ np.array([u, v]) * dt
    p = p + g @ q @ g.T
    a = (F_PX / Z_M) * r.T
    h_full = np.zeros((2, n))
    h_full[:, 0:2] = -a
    h_full[:, k : k + 2] = a
    s = h_full @ p @ h_full.T + r_m
    gain = p @ h_full.T @ np.linalg.inv(s)
    i_kh = np.eye(n) - gain @ h_full
    x = x + gain @ (mn - a @ (x[k : k + 2] - x[0:2]))
    return x, i_kh @ p @ i_kh.T + gain @ r_m @ gain.T


def time_ours(ekf: EkfSlam, repeats: int, rng) -> tuple[float, int]:
    n = ekf.n_landmarks
    times, accepted = [], 0
    for _ in range(repeats):
        i = int(rng.integers(n))
        psi = float(rng.uniform(-np.pi, np.pi))
        # Zero speed, so the observation computed before the timer is still the prediction.
        mn, _ = ekf.predict_observation(i, psi, Z_M, F_PX)
        mn = mn + rng.normal(0.0, 0.5, 2)
        t0 = time.perf_counter()
        ekf.predict(MotionInput(0.0, 0.0, Q, psi, DT_S))
        res = ekf.update(i, mn, psi, Z_M, F_PX)
        times.append(time.perf_counter() - t0)
        accepted += res.accepted
    return float(np.median(times)), accepted


def time_dense(ekf: EkfSlam, repeats: int, rng) -> float:
    x, p = ekf.state_m, ekf.covariance_m2
    times = []
    for _ in range(repeats):
        i = int(rng.integers(ekf.n_landmarks))
        psi = float(rng.uniform(-np.pi, np.pi))
        mn, _ = ekf.predict_observation(i, psi, Z_M, F_PX)
        r_m = observation_noise_px2(mn, 0.5, Z_M)
        t0 = time.perf_counter()
        v = ekf.state_dim - 2 * ekf.n_landmarks  # vehicle block: x, y (, heading bias)
        dense_predict_update(x, p, v + 2 * i, mn, psi, r_m, 0.0, 0.0, Q, DT_S)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def time_gate_and_augment(ekf: EkfSlam, repeats: int) -> tuple[float, float]:
    gate = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        ekf.visible_landmarks(0.3, Z_M, F_PX, W_PX, H_PX)
        ekf.may_add_landmark()
        gate.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    ekf.augment([10.0, -20.0], 0.3, Z_M, F_PX)
    return float(np.median(gate)), time.perf_counter() - t0


def main(args: argparse.Namespace) -> int:
    rng = np.random.default_rng(1)
    print(f"EKF-SLAM predict + update, median of {args.repeats} (BLAS threads: {args.threads})")
    header = (
        f"{'N':>6} {'state':>6} {'rovslam ms':>11} {'dense ms':>10} {'ratio':>8} {'gate+(6) ms':>12} {'augment ms':>11}"
    )
    print(header)
    print("-" * len(header))
    dense_ref = None
    for n in args.sizes:
        ekf = build(n)
        dim = ekf.state_dim
        ours, accepted = time_ours(ekf, args.repeats, rng)
        if accepted != args.repeats:
            print(f"warning: {args.repeats - accepted} updates rejected at N={n}", file=sys.stderr)
        if n <= args.dense_max:
            dense = time_dense(ekf, max(3, min(args.repeats, int(2e6 / (2 + 2 * n) ** 2))), rng)
            dense_ref = (n, dense)
            dense_txt = f"{dense * 1e3:10.2f}"
        elif dense_ref is not None:
            dense = dense_ref[1] * ((2 + 2 * n) / (2 + 2 * dense_ref[0])) ** 3
            dense_txt = f"~{dense * 1e3:9.0f}"
        else:
            dense, dense_txt = float("nan"), f"{'-':>10}"
        gate, aug = time_gate_and_augment(ekf, min(args.repeats, 20))
        print(
            f"{n:6d} {dim:6d} {ours * 1e3:11.3f} {dense_txt} {dense / ours:8.1f} {gate * 1e3:12.3f} {aug * 1e3:11.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(ARGS))
