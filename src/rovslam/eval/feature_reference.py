"""Evaluation with no ground truth: each processed frame pair's token motion against the feature motion.

For every pair of consecutive processed frames of a run (``trajectory.csv`` rows not skipped),
the frames are read again from the run's input and the seabed's motion between them is measured
by an independent method, point features (:func:`rovslam.vision.features.feature_motion`). Both
motions are compared as the same quantity: where the previous image's pixel now under the
principal point was, ``p - c`` in pixels of the previous image. From the tokens::

    [a, b] = R(-gamma) [surge, sway] dt,   p - c = [b fx / Z, -a fy / Z]

(``gamma`` the camera's yaw offset, ``Z`` the previous frame's altitude of ``trajectory.csv``,
``dt`` the frames' interval, the speed of the later row, measured or, where the tokens measured
none, the speed the run held; a level camera, no lever arm, as ``eval.baselines``). From the features: the similarity of the current frame onto the previous
(keypoints freed of the lens distortion), applied to the principal point. A pair agrees when the two differ by at most 10 % of the token
motion, or by at most 2 sigma (Mahalanobis distance of the difference under the sum of the two
covariances: the speed's Q times dt^2 in pixels, and the features' from their inliers).

A frame whose speed the run took from the feature motion itself (``trajectory.csv``
``speed_source = features``: the tokens were weak under a large motion) is not compared: the
method would be checked against itself. Such pairs are counted under ``not_compared``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import InvalidArgumentError, ResultsFormatError

RELATIVE_TOLERANCE = 0.10  # agreement within 10 % of the token motion ...
SIGMA_TOLERANCE = 2.0  # ... or within 2 sigma


@dataclass(frozen=True)
class PairComparison:
    """One processed frame pair: the two motions ``p - c`` ``(2,)`` px, their difference and whether they agree.

    ``frame_prev`` / ``frame``: the input's frame numbers. ``held``: the tokens measured no speed
    at ``frame`` and the run moved by the speed it held (compared all the same: it is the motion
    the run integrated). ``reason``: why the pair could not be compared ("" when compared): no
    speed at all, a speed the run took from the feature motion (not independent), an unreadable
    frame, or no reliable feature motion.
    """

    frame_prev: int
    frame: int
    t_s: float
    token_px: np.ndarray
    feature_px: np.ndarray
    relative: float = float("nan")
    mahalanobis: float = float("nan")
    reason: str = ""
    held: bool = False

    @property
    def compared(self) -> bool:
        return not self.reason

    @property
    def within_relative(self) -> bool:
        return self.compared and self.relative <= RELATIVE_TOLERANCE

    @property
    def within_sigma(self) -> bool:
        return self.compared and self.mahalanobis <= SIGMA_TOLERANCE

    @property
    def agrees(self) -> bool:
        return self.within_relative or self.within_sigma

    @property
    def badness(self) -> float:
        """How far from agreeing: the smaller of the relative difference over 10 % and the sigmas over 2 (> 1: disagrees)."""
        return min(self.relative / RELATIVE_TOLERANCE, self.mahalanobis / SIGMA_TOLERANCE) if self.compared else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame_prev": self.frame_prev,
            "frame": self.frame,
            "t_s": self.t_s,
            "token_px": [float(v) for v in self.token_px],
            "feature_px": [float(v) for v in self.feature_px],
            "difference_px": float(np.linalg.norm(self.feature_px - self.token_px)),
            "relative": self.relative,
            "mahalanobis": self.mahalanobis,
            "agrees": self.agrees,
            "held": self.held,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class FeatureReference:
    """The comparison of a run's frame pairs (``eval.json`` ``feature_reference``)."""

    pairs: list[PairComparison] = field(default_factory=list)
    worst_count: int = 5

    @property
    def compared(self) -> list[PairComparison]:
        return [p for p in self.pairs if p.compared]

    def share(self, what: str) -> float:
        """Share of the compared pairs that ``agrees``, are ``within_relative`` or ``within_sigma``; NaN if none."""
        done = self.compared
        return float(np.mean([getattr(p, what) for p in done])) if done else float("nan")

    def worst(self) -> list[PairComparison]:
        """The compared pairs farthest from agreeing (:attr:`PairComparison.badness`), at most ``worst_count``."""
        return sorted(self.compared, key=lambda p: -p.badness)[: self.worst_count]

    def to_dict(self) -> dict[str, Any]:
        reasons: dict[str, int] = {}
        for p in self.pairs:
            if p.reason:
                key = p.reason.split(" (")[0]
                reasons[key] = reasons.get(key, 0) + 1
        return {
            "method": "ORB features, RANSAC similarity (rovslam.vision.features)",
            "tolerance": {"relative": RELATIVE_TOLERANCE, "sigma": SIGMA_TOLERANCE},
            "pairs": len(self.pairs),
            "compared": len(self.compared),
            "agree_share": self.share("agrees"),
            "within_relative_share": self.share("within_relative"),
            "within_sigma_share": self.share("within_sigma"),
            "held_compared": sum(p.held for p in self.compared),
            "not_compared": reasons,
            "not_compared_pairs": [[p.frame_prev, p.frame, p.reason] for p in self.pairs if p.reason][:50],
            "worst": [p.to_dict() for p in self.worst()],
            # every compared pair, for the report's figure: frame, t_s, |token| px, |feature| px, difference px, relative,
            # sigmas, agrees (1/0), held (1/0)
            "per_pair": [
                [
                    p.frame,
                    p.t_s,
                    float(np.linalg.norm(p.token_px)),
                    float(np.linalg.norm(p.feature_px)),
                    float(np.linalg.norm(p.feature_px - p.token_px)),
                    p.relative,
                    p.mahalanobis,
                    int(p.agrees),
                    int(p.held),
                ]
                for p in self.compared
            ],
        }


def token_motion_px(
    speed_mps: np.ndarray, speed_cov_mps2: np.ndarray, dt_s: float, altitude_m: float, camera: Any
) -> tuple[np.ndarray, np.ndarray]:
    """The token speed ``(2,)`` [surge, sway] m/s with ``(2, 2)`` Q as ``p - c`` ``(2,)`` px and ``(2, 2)`` px^2.

    ``camera``: a :class:`rovslam.camera.Camera` (``fx_px``, ``fy_px``, ``yaw_offset_rad``).
    """
    v = np.asarray(speed_mps, dtype=np.float64)
    q = np.asarray(speed_cov_mps2, dtype=np.float64)
    if v.shape != (2,) or q.shape != (2, 2) or not (dt_s > 0 and altitude_m > 0):
        raise InvalidArgumentError(
            f"need a (2,) speed, a (2, 2) covariance, dt_s > 0 and altitude_m > 0; got {v.shape}, {q.shape}, "
            f"{dt_s}, {altitude_m}"
        )
    g = camera.yaw_offset_rad
    unrotate = np.array([[math.cos(g), math.sin(g)], [-math.sin(g), math.cos(g)]])  # R(-gamma)
    to_px = np.array([[0.0, camera.fx_px / altitude_m], [-camera.fy_px / altitude_m, 0.0]]) @ unrotate * dt_s
    return to_px @ v, to_px @ q @ to_px.T


def compare_pair(
    token_px: np.ndarray, token_cov_px2: np.ndarray, feature_px: np.ndarray, feature_cov_px2: np.ndarray
) -> tuple[float, float]:
    """``(relative, mahalanobis)``: the difference's size over the token motion's, and in sigmas of both covariances."""
    diff = np.asarray(feature_px, dtype=np.float64) - np.asarray(token_px, dtype=np.float64)
    norm = float(np.linalg.norm(token_px))
    relative = float(np.linalg.norm(diff)) / norm if norm > 0 else (0.0 if not diff.any() else math.inf)
    cov = np.asarray(token_cov_px2) + np.asarray(feature_cov_px2)
    try:
        maha = math.sqrt(max(float(diff @ np.linalg.solve(cov, diff)), 0.0))
    except np.linalg.LinAlgError:
        maha = 0.0 if not diff.any() else math.inf
    return relative, maha


def feature_reference(results_dir: str | Path, worst_count: int = 5) -> FeatureReference:
    """Compare every processed frame pair of the run in ``results_dir`` with the feature motion of its input.

    The input and the camera file are those ``summary.json`` names (``sequence``,
    ``camera_file``, ``inputs``). Raises :class:`ResultsFormatError` when the run names no
    readable input, or its frames no longer match the run's times.
    """
    from rovslam.io.run_results import read_results

    run = read_results(results_dir)
    source = _open_input(Path(results_dir), run.summary)
    camera = source.info.camera
    traj = run.trajectory
    keep = np.nonzero(traj["skipped"] == 0)[0] if "skipped" in traj else np.arange(len(run.t_s))
    q_all = run.speed_cov_mps2
    pairs = []
    for (i_prev, prev), (i, cur) in _pairwise(_frames_at(source, run.t_s[keep], keep, Path(results_dir))):
        dt_s = float(traj["t_s"][i] - traj["t_s"][i_prev])
        pairs.append(_pair(traj, q_all, i_prev, i, prev, cur, dt_s, camera))
    return FeatureReference(pairs, worst_count)


def _pair(traj: dict, q_all: np.ndarray | None, i_prev: int, i: int, prev: Any, cur: Any, dt_s: float, camera: Any):
    from rovslam.vision.features import feature_motion, point_motion_px

    nan2 = np.full(2, np.nan)
    base = {"frame_prev": prev.index, "frame": cur.index, "t_s": float(traj["t_s"][i])}
    speed = np.array([traj["surge_mps"][i], traj["sway_mps"][i]])
    altitude_m = float(traj["altitude_m"][i_prev])
    base["held"] = bool(traj["speed_ok"][i] != 1)
    if not (np.all(np.isfinite(speed)) and altitude_m > 0 and dt_s > 0):
        return PairComparison(**base, token_px=nan2, feature_px=nan2, reason="no speed")
    if "speed_source" in traj and traj["speed_source"][i] == "features":
        return PairComparison(**base, token_px=nan2, feature_px=nan2, reason="speed from the feature motion")
    q = q_all[i] if q_all is not None and np.all(np.isfinite(q_all[i])) else np.zeros((2, 2))
    tok_px, tok_cov = token_motion_px(speed, q, dt_s, altitude_m, camera)
    if prev.image is None or cur.image is None:
        return PairComparison(**base, token_px=tok_px, feature_px=nan2, reason="unreadable frame")
    motion = feature_motion(cur.image, prev.image, camera=camera)  # the current frame onto the previous one
    if not motion.ok:
        return PairComparison(**base, token_px=tok_px, feature_px=nan2, reason=f"no feature motion ({motion.reason})")
    feat_px, feat_cov = point_motion_px(motion, np.array([camera.cx_px, camera.cy_px]))
    relative, maha = compare_pair(tok_px, tok_cov, feat_px, feat_cov)
    return PairComparison(**base, token_px=tok_px, feature_px=feat_px, relative=relative, mahalanobis=maha)


def _pairwise(items: Iterator[Any]) -> Iterator[tuple[Any, Any]]:
    prev = None
    for item in items:
        if prev is not None:
            yield prev, item
        prev = item


def _frames_at(source: Any, t_s: np.ndarray, rows: np.ndarray, where: Path, tol_s: float = 1e-4) -> Iterator[Any]:
    """``(row, frame)`` for each time of ``t_s`` (in order), streamed from the source; ResultsFormatError if one is missing."""
    j = 0
    for frame in source.frames():
        if j >= len(t_s):
            return
        if frame.t_s > t_s[j] + tol_s:
            break
        if abs(frame.t_s - t_s[j]) <= tol_s:
            yield int(rows[j]), frame
            j += 1
    if j < len(t_s):
        raise ResultsFormatError(
            f"{where / 'trajectory.csv'}: the run's input has no frame at t_s={t_s[j]:.6f}; "
            "the input summary.json names is not the one the run read (moved or changed since)."
        )


def _open_input(results_dir: Path, summary: dict[str, Any]) -> Any:
    """The run's input opened as ``rovslam run`` opened it (``summary.json``: sequence, camera_file, inputs)."""
    from rovslam.io.source import InputOptions
    from rovslam.runner import open_source

    seq = summary.get("sequence")
    if not isinstance(seq, str) or not Path(seq).exists():
        raise ResultsFormatError(
            f"{results_dir / 'summary.json'}: names no input that exists ('sequence': {seq!r}); "
            "the feature reference re-reads the run's frames: put the input back where the run read it."
        )
    given = summary.get("inputs") or {}
    opts: dict[str, Any] = {}
    for key in ("camera_file", "times_file", "nav_file"):
        name = "nav" if key == "nav_file" else key
        if isinstance(given.get(name), str):
            opts[key] = Path(given[name])
    if isinstance(summary.get("camera_file"), str):
        opts["camera_file"] = Path(summary["camera_file"])
    if isinstance(given.get("fps"), (int, float)):
        opts["fps"] = float(given["fps"])
    if isinstance(given.get("nav_time_offset"), (int, float)):
        opts["nav_time_offset_s"] = float(given["nav_time_offset"])
    if isinstance(given.get("nav_map"), list):
        opts["nav_map"] = tuple(tuple(str(s).split("=", 1)) for s in given["nav_map"] if "=" in str(s))
    for key in ("image_topic", "heading_topic", "altitude_topic", "attitude_topic", "camera_info_topic"):
        if isinstance(given.get(key), str):
            opts[key] = given[key]
    if isinstance(given.get("heading_convention"), str):
        opts["heading_convention"] = given["heading_convention"]
    opts["heading_degrees"] = bool(given.get("heading_degrees", False))
    return open_source(seq, options=InputOptions(**opts))
