"""Label placement that never overlaps: each label takes the nearest free spot around its point.

Works in display units (pixels), on axis-aligned boxes. Candidates are tried ring by ring
(8 directions per ring, the ring radius growing by one label height), and a candidate is
free when its box overlaps no label placed before it and covers no anchor point. A label
moved beyond the first ring gets a leader line back to its point. Greedy and deterministic:
labels are placed in the order given, which the caller sets (e.g. most important first).
"""

from __future__ import annotations

import numpy as np

_DIRECTIONS = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1], [1, 0], [0, 1], [-1, 0], [0, -1]], dtype=float)


def _overlaps(box: np.ndarray, boxes: np.ndarray) -> bool:
    """Whether ``box`` (4,) [x0, y0, x1, y1] overlaps any of ``boxes`` (N, 4)."""
    if len(boxes) == 0:
        return False
    return bool(
        np.any((box[0] < boxes[:, 2]) & (boxes[:, 0] < box[2]) & (box[1] < boxes[:, 3]) & (boxes[:, 1] < box[3]))
    )


def _covers(box: np.ndarray, pts: np.ndarray, pad: float) -> bool:
    if len(pts) == 0:
        return False
    return bool(
        np.any(
            (pts[:, 0] > box[0] - pad)
            & (pts[:, 0] < box[2] + pad)
            & (pts[:, 1] > box[1] - pad)
            & (pts[:, 1] < box[3] + pad)
        )
    )


def place_labels(
    anchors_px: np.ndarray,
    sizes_px: np.ndarray,
    obstacles_px: np.ndarray | None = None,
    gap_px: float = 2.0,
    max_rings: int = 60,
    bounds_px: tuple[float, float, float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Centres of non-overlapping label boxes near their anchors.

    ``anchors_px`` (N, 2) label anchor points, ``sizes_px`` (N, 2) label (width, height),
    ``obstacles_px`` (M, 2) points no label may cover (the anchors are always obstacles).
    Returns ``(centres (N, 2), moved (N,) bool)``: ``moved`` marks labels placed beyond the
    first ring, which should get a leader line. Boxes are separated by ``gap_px``; with
    ``bounds_px`` (x0, y0, x1, y1) they stay inside that box while there is room.
    """
    bounds = None if bounds_px is None else np.asarray(bounds_px, dtype=float)
    anchors = np.asarray(anchors_px, dtype=float).reshape(-1, 2)
    sizes = np.asarray(sizes_px, dtype=float).reshape(-1, 2)
    obst = anchors if obstacles_px is None else np.vstack([anchors, np.asarray(obstacles_px, float).reshape(-1, 2)])
    placed = np.zeros((0, 4))
    centres = np.zeros_like(anchors)
    moved = np.zeros(len(anchors), dtype=bool)
    for k, (a, (w, h)) in enumerate(zip(anchors, sizes)):
        half = np.array([w / 2 + gap_px / 2, h / 2 + gap_px / 2])
        best = None
        for ring in range(max_rings):
            r = 3.0 + ring * (h + gap_px)
            for d in _DIRECTIONS:
                c = a + d * (half + r)
                box = np.array([c[0] - half[0], c[1] - half[1], c[0] + half[0], c[1] + half[1]])
                inside = bounds is None or (
                    box[0] >= bounds[0] and box[1] >= bounds[1] and box[2] <= bounds[2] and box[3] <= bounds[3]
                )
                if inside and not _overlaps(box, placed) and not _covers(box, obst, 1.5):
                    best = (c, box, ring)
                    break
            if best is not None:
                break
        if best is None:  # crowded beyond max_rings: stack it above every placed box
            top = float(placed[:, 3].max()) if len(placed) else a[1]
            c = np.array([a[0], top + half[1] + gap_px])
            best = (c, np.array([c[0] - half[0], c[1] - half[1], c[0] + half[0], c[1] + half[1]]), max_rings)
        centres[k] = best[0]
        moved[k] = best[2] > 0
        placed = np.vstack([placed, best[1]])
    return centres, moved


def label_points(ax, xy: np.ndarray, texts: list[str], obstacles_xy: np.ndarray | None = None, **text_kw) -> list:
    """Annotate points ``xy`` (N, 2, data units) of a matplotlib axes with non-overlapping labels.

    Call after the axes limits are final (the placement is done in display pixels).
    """
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    trans = ax.transData
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) == 0:
        return []
    anchors = trans.transform(xy)
    sizes = []
    for s in texts:
        t = ax.text(0, 0, s, **text_kw)
        bb = t.get_window_extent(renderer)
        sizes.append((bb.width, bb.height))
        t.remove()
    obst = None if obstacles_xy is None or len(obstacles_xy) == 0 else trans.transform(np.asarray(obstacles_xy, float))
    bb = ax.get_window_extent(renderer)
    centres, moved = place_labels(anchors, np.asarray(sizes), obst, bounds_px=(bb.x0, bb.y0, bb.x1, bb.y1))
    inv = trans.inverted()
    out = []
    colour = text_kw.get("color", "k")
    for s, a, c, m in zip(texts, xy, inv.transform(centres), moved):
        arrow = {"arrowstyle": "-", "lw": 0.5, "color": colour, "shrinkA": 0, "shrinkB": 1} if m else None
        out.append(
            ax.annotate(
                s,
                a,
                xytext=c,
                textcoords="data",
                ha="center",
                va="center",
                arrowprops=arrow,
                annotation_clip=False,
                **text_kw,
            )
        )
    return out
