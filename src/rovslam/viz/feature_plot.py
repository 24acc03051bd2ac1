"""The report's figure of the feature reference: each frame pair's token motion against the feature motion.

Read from ``eval.json``'s ``feature_reference`` block (``rovslam eval OUT --reference features``):
the top panel shows both motions per pair (``|p - c|`` px, :mod:`rovslam.eval.feature_reference`),
the bottom one how far each pair is from agreeing (the relative difference over its 10 % and the
sigmas over their 2, the smaller: above 1 the pair disagrees), the worst pairs marked with their
frame numbers. Without ``per_pair`` (an older ``eval.json``) only the worst pairs are drawn.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.viz.plots import pyplot, save_figure

__all__ = ["feature_reference_caption", "feature_reference_pairs", "plot_feature_reference"]

_COLUMNS = ("frame", "t_s", "token_px", "feature_px", "difference_px", "relative", "mahalanobis", "agrees", "held")


def _number(value: Any) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return float("nan")
    return x


def feature_reference_pairs(block: dict[str, Any]) -> dict[str, np.ndarray]:
    """The block's pairs as columns ``(K,)`` each (``_COLUMNS``); from ``worst`` when ``per_pair`` is absent.

    Rows that are not lists of 9 numbers (a damaged file) are left out.
    """
    rows = block.get("per_pair")
    if not isinstance(rows, list):
        rows = [
            [w.get("frame"), w.get("t_s"), _norm(w.get("token_px")), _norm(w.get("feature_px")), w.get("difference_px"),
             w.get("relative"), w.get("mahalanobis"), int(bool(w.get("agrees"))), int(bool(w.get("held")))]
            for w in block.get("worst", []) if isinstance(w, dict)
        ]  # fmt: skip
    table = [[_number(v) for v in r] for r in rows if isinstance(r, list) and len(r) == len(_COLUMNS)]
    arr = np.array(table, dtype=np.float64).reshape(-1, len(_COLUMNS))
    arr = arr[np.isfinite(arr[:, 1])] if len(arr) else arr
    arr = arr[np.argsort(arr[:, 1], kind="stable")]
    return {name: arr[:, i] for i, name in enumerate(_COLUMNS)}


def _norm(v: Any) -> float:
    try:
        return float(np.linalg.norm(np.asarray(v, dtype=np.float64)))
    except (TypeError, ValueError):
        return float("nan")


def _badness(cols: dict[str, np.ndarray], tol: dict[str, Any]) -> np.ndarray:
    rel = _number(tol.get("relative", 0.1)) if isinstance(tol, dict) else 0.1
    sig = _number(tol.get("sigma", 2.0)) if isinstance(tol, dict) else 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.fmin(cols["relative"] / rel, cols["mahalanobis"] / sig)


def plot_feature_reference(block: dict[str, Any], path: Path, worst_count: int = 5) -> Path | None:
    """Write the figure to ``path`` (PNG); None when the block holds no compared pair."""
    cols = feature_reference_pairs(block)
    if len(cols["t_s"]) == 0:
        return None
    bad = _badness(cols, block.get("tolerance", {}))
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    t = cols["t_s"]
    top.plot(t, cols["token_px"], ".-", ms=3, lw=0.8, label="tokens (the run's speed)")
    top.plot(t, cols["feature_px"], ".", ms=3, label="features (reference)")
    held = cols["held"] > 0
    if held.any():
        top.plot(t[held], cols["token_px"][held], "o", mfc="none", color="tab:orange", label="speed held")
    top.set_ylabel("motion |p - c| (px)")
    top.legend(loc="upper right", fontsize=8)
    agrees = cols["agrees"] > 0
    bottom.semilogy(t[agrees], np.maximum(bad[agrees], 1e-3), ".", ms=3, color="tab:green", label="agree")
    bottom.semilogy(t[~agrees], np.maximum(bad[~agrees], 1e-3), ".", ms=4, color="tab:red", label="disagree")
    bottom.axhline(1.0, color="k", lw=0.8, ls="--")
    order = np.argsort(-np.nan_to_num(bad, nan=-math.inf), kind="stable")[:worst_count]
    for i in order:
        if np.isfinite(bad[i]):
            bottom.plot(t[i], max(bad[i], 1e-3), "x", color="k", ms=8)
            bottom.annotate(f"{int(cols['frame'][i])}", (t[i], max(bad[i], 1e-3)), textcoords="offset points",
                            xytext=(4, 4), fontsize=8)  # fmt: skip
    bottom.set_ylabel("distance from agreeing\n(> 1: disagree)")
    bottom.set_xlabel("time (s)")
    bottom.legend(loc="upper right", fontsize=8)
    fig.suptitle(feature_reference_caption(block))
    fig.tight_layout()
    return save_figure(fig, path)


def feature_reference_caption(block: dict[str, Any]) -> str:
    """One line: how many pairs were compared and the share that agree."""
    share = _number(block.get("agree_share"))
    compared = block.get("compared", 0)
    pairs = block.get("pairs", 0)
    agree = "n/a" if not math.isfinite(share) else f"{100 * share:.1f} %"
    return f"Feature reference: {compared} of {pairs} frame pairs compared, {agree} agree (worst marked x)"
