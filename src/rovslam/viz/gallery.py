"""Figures 5 and 6 of the paper: the camera views when a landmark is initialised and revisited.

For each chosen landmark, one column per passage (its initialisation, then the first
accepted observation of every later passage, see :func:`rovslam.viz.runinfo.passages`):

* the frame, with the landmark's 32x32 box and that frame's tracked 16x16 speed tokens drawn;
* the landmark template as cut at initialisation beside the image patch matched there,
  magnified, with the time, the normalised correlation and the NIS of the update.

Frames come from the run's sequence or video (:mod:`rovslam.viz.frames`); when it is gone,
the crops the run saved under ``OUT/revisits/`` stand in, and the figure says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rovslam.io.run_results import RunResults
from rovslam.viz.plots import pyplot, save_figure
from rovslam.viz.runinfo import passages

LANDMARK_PX = 32
TOKEN_PX = 16


@dataclass(frozen=True)
class View:
    """One passage of a landmark: where and how well it was matched."""

    landmark_id: int
    frame: int
    t_s: float
    kind: str  # "init" | "track"
    score: float
    nis: float
    uv_px: np.ndarray  # (2,)
    tokens_uv_px: np.ndarray  # (K, 2) speed tokens tracked in that frame
    image: np.ndarray | None = None  # (H, W, 3) uint8 frame, when available
    crop: np.ndarray | None = None  # (S, S, 3) uint8 saved crop around uv, when the frame is not


def select_views(res: RunResults, landmark_id: int, max_views: int = 6) -> list[View]:
    """The initialisation and up to ``max_views - 1`` revisits (evenly spread over the run) of a landmark."""
    rows = passages(res, landmark_id)
    if len(rows) > max_views:
        keep = np.unique(np.round(np.linspace(0, len(rows) - 1, max_views)).astype(int))
        rows = [rows[k] for k in keep]
    obs = res.observations
    kinds = np.asarray(obs.get("kind", np.full(len(obs["t_s"]), "track")), dtype=str) if rows else []  # type: ignore[var-annotated]
    return [
        View(
            landmark_id,
            int(obs["frame"][r]),
            float(obs["t_s"][r]),
            str(kinds[r]),
            float(obs["score"][r]),
            float(obs["nis"][r]),
            np.array([obs["u_px"][r], obs["v_px"][r]]),
            np.zeros((0, 2)),
        )
        for r in rows
    ]


def attach_images(
    views: list[View], images: dict[int, np.ndarray], tokens: dict[int, np.ndarray], out_dir: Path
) -> list[View]:
    """Views with their frame (or the saved crop) and speed tokens filled in."""
    import cv2

    out = []
    for v in views:
        crop = None
        img = images.get(v.frame)
        if img is None:
            p = out_dir / "revisits" / str(v.landmark_id) / f"{v.frame}.png"
            if p.is_file():
                bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
                crop = None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        out.append(
            View(
                v.landmark_id,
                v.frame,
                v.t_s,
                v.kind,
                v.score,
                v.nis,
                v.uv_px,
                tokens.get(v.frame, np.zeros((0, 2))),
                img,
                crop,
            )
        )
    return out


def _patch(view: View, size: int = LANDMARK_PX) -> np.ndarray | None:
    import cv2

    src = view.image if view.image is not None else view.crop
    if src is None:
        return None
    centre = (
        tuple(float(c) for c in view.uv_px)
        if view.image is not None
        else ((src.shape[1] - 1) / 2, (src.shape[0] - 1) / 2)
    )
    return cv2.getRectSubPix(np.ascontiguousarray(src), (size, size), centre)


def _box(ax, uv, side, **kw) -> None:
    from matplotlib.patches import Rectangle

    ax.add_patch(Rectangle((uv[0] - side / 2, uv[1] - side / 2), side, side, fill=False, **kw))


def plot_gallery(
    blocks: list[tuple[int, list[View], np.ndarray | None]], path: Path, title: str, note: str = ""
) -> Path:
    """One block of two rows per landmark: ``(landmark id, views, template (32, 32) uint8 or None)``."""
    plt = pyplot()
    n_cols = max([len(v) for _, v, _ in blocks] + [3])  # at least 3 columns: room for the title
    n_rows = 2 * len(blocks)
    fig, axes = plt.subplots(
        n_rows,
        n_cols,
        figsize=(2.5 * n_cols + 0.4, 3.4 * len(blocks) + 0.7),
        gridspec_kw={"height_ratios": [2.0, 1.0] * len(blocks), "hspace": 0.5},
        squeeze=False,
    )
    for a in axes.ravel():
        a.axis("off")
    for b, (lid, views, template) in enumerate(blocks):
        top, bottom = axes[2 * b], axes[2 * b + 1]
        if not views:
            top[0].text(0, 0.5, f"landmark {lid}: never observed", fontsize=9)
            continue
        for c, v in enumerate(views):
            ax = top[c]
            what = "initialised" if v.kind == "init" else "revisit"
            if v.image is not None:
                ax.imshow(v.image)
                _box(ax, v.uv_px, LANDMARK_PX, ec="yellow", lw=1.2)
                for tok in v.tokens_uv_px:
                    _box(ax, tok, TOKEN_PX, ec="lime", lw=0.7)
                ax.set_xlim(-0.5, v.image.shape[1] - 0.5)
                ax.set_ylim(v.image.shape[0] - 0.5, -0.5)
            elif v.crop is not None:
                ax.imshow(v.crop, interpolation="nearest")
                _box(ax, ((v.crop.shape[1] - 1) / 2, (v.crop.shape[0] - 1) / 2), LANDMARK_PX, ec="yellow", lw=1.2)
            else:
                ax.text(0.5, 0.5, "frame not\navailable", ha="center", va="center", fontsize=8, transform=ax.transAxes)
            ax.set_title(f"L{lid} {what}, frame {v.frame}\nt = {v.t_s:.1f} s, {len(v.tokens_uv_px)} tokens", fontsize=8)
            patch = _patch(v)
            strip = []
            if template is not None:
                strip.append(np.repeat(template[:, :, None], 3, axis=2))
            if patch is not None:
                if strip:
                    strip.append(np.full((LANDMARK_PX, 3, 3), 255, np.uint8))
                strip.append(patch)
            ax2 = bottom[c]
            if strip:
                ax2.imshow(np.hstack(strip), interpolation="nearest")
            caption = (
                "template | matched patch"
                if template is not None and patch is not None
                else ("matched patch" if patch is not None else "template")
            )
            stats = "" if v.kind == "init" else f"\ncorr {v.score:.3f}, NIS {v.nis:.2f}"
            ax2.set_title(caption + stats, fontsize=7.5)
    fig.suptitle(title, fontsize=11)
    if note:
        import textwrap

        fig.text(
            0.5,
            0.005,
            textwrap.fill(note, int(14 * fig.get_figwidth())),
            ha="center",
            va="bottom",
            fontsize=8,
            color="tab:red",
        )
    fig.subplots_adjust(
        left=0.01, right=0.99, top=1 - 0.75 / fig.get_figheight(), bottom=0.1 if note else 0.02, wspace=0.08
    )
    return save_figure(fig, path)


def read_template(out_dir: Path, landmark_id: int) -> np.ndarray | None:
    """``OUT/landmarks/<id>.png`` as (32, 32) uint8, or None."""
    import cv2

    p = out_dir / "landmarks" / f"{landmark_id}.png"
    if not p.is_file():
        return None
    return cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
