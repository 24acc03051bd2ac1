"""One self-contained HTML report of a run, with the PNG figures beside it.

``write_report(OUT)`` writes ``OUT/report/index.html`` and the figures (``altitude_speed.png``,
``position.png``, ``map.png``, ``fig5_landmark_<id>.png``,
``fig6_landmarks.png``, ``mosaic.png`` / ``mosaic_truth.png``, ``feature_reference.png`` when
``eval.json`` holds the feature reference). Every image is embedded in
the HTML as a data URI, so the file opens offline, can be copied alone or mailed.

Everything is computed from the result files (:mod:`rovslam.viz.runinfo`); a frame source
or a ground truth that is missing is said in the report, never a failure.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rovslam.errors import RovslamError
from rovslam.io.output import (
    atomic_write_bytes,
    atomic_write_text,
    check_output_folder,
    output_errors,
)
from rovslam.io.run_results import RunResults, read_results
from rovslam.viz import gallery, plots, runinfo

_CSS = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:auto;padding:0 12px;color:#222}
img{max-width:100%;height:auto}
table{border-collapse:collapse;margin:6px 0}
td,th{padding:2px 10px;text-align:right;border-bottom:1px solid #e4e4e4}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
.warn{background:#fff3cd;border:1px solid #e0b000;padding:6px 10px;margin:6px 0}
.note{color:#a33}
.keys{display:flex;flex-wrap:wrap;gap:8px}
.key{border:1px solid #ddd;border-radius:4px;padding:4px 10px;min-width:120px}
.key b{display:block;font-size:1.25em}
.pair{display:flex;gap:8px}.pair figure{flex:1;margin:0}
pre{background:#f7f7f7;padding:8px;overflow:auto;font-size:12px}
"""


@dataclass
class Report:
    """What the report shows, assembled before it is written (figures are file paths)."""

    title: str
    keys: list[tuple[str, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    sections: list[str] = field(default_factory=list)  # HTML fragments in order


def data_uri(path: Path, mime: str | None = None) -> str:
    """``data:`` URI of a file (PNG or JPEG)."""
    mime = mime or ("image/jpeg" if path.suffix.lower() in (".jpg", ".jpeg") else "image/png")
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _img(path: Path, alt: str, caption: str = "") -> str:
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return f"<figure><img src='{data_uri(path)}' alt='{html.escape(alt)}'>{cap}</figure>"


def _fmt_cm(v_m: float) -> str:
    return f"{100 * v_m:.2f} cm" if math.isfinite(v_m) else "n/a"


def table1(res: RunResults, gt_xy_m: np.ndarray | None, landmark_id: int = 0) -> list[dict[str, float]]:
    """The paper's Table 1: vehicle displacement since landmark ``landmark_id`` was initialised, at each passage."""
    rows = runinfo.passages(res, landmark_id)
    if not rows:
        return []
    t = res.t_s
    k_of = [int(np.clip(np.searchsorted(t, res.observations["t_s"][r] - 1e-6), 0, len(t) - 1)) for r in rows]
    est = res.xy_m
    sd = plots.sigma_m(res)
    k0 = k_of[0]
    out = []
    for k in k_of:
        row = {
            "t_s": float(t[k]),
            "x_est_m": float(est[k, 0] - est[k0, 0]),
            "y_est_m": float(est[k, 1] - est[k0, 1]),
            "sigma_x_m": float(sd[k, 0]),
            "sigma_y_m": float(sd[k, 1]),
        }
        if gt_xy_m is not None:
            row["x_gt_m"] = float(gt_xy_m[k, 0] - gt_xy_m[k0, 0])
            row["y_gt_m"] = float(gt_xy_m[k, 1] - gt_xy_m[k0, 1])
        out.append(row)
    return out


def _table1_html(rows: list[dict[str, float]], landmark_id: int, limit: int = 40) -> str:
    if not rows:
        return f"<p>Landmark {landmark_id} was never observed.</p>"
    gt = "x_gt_m" in rows[0]
    head = (
        "<tr><th>time [s]</th><th>x&#770; [m]</th><th>y&#770; [m]</th><th>2&sigma; x [cm]</th><th>2&sigma; y [cm]</th>"
    )
    head += "<th>x<sub>GT</sub> [m]</th><th>y<sub>GT</sub> [m]</th><th>error [cm]</th></tr>" if gt else "</tr>"
    body = []
    for r in rows[:limit]:
        cells = [
            f"{r['t_s']:.1f}",
            f"{r['x_est_m']:.3f}",
            f"{r['y_est_m']:.3f}",
            f"{200 * r['sigma_x_m']:.2f}",
            f"{200 * r['sigma_y_m']:.2f}",
        ]
        if gt:
            err = math.hypot(r["x_est_m"] - r["x_gt_m"], r["y_est_m"] - r["y_gt_m"])
            cells += [f"{r['x_gt_m']:.3f}", f"{r['y_gt_m']:.3f}", f"{100 * err:.2f}"]
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    more = f"<p>({len(rows) - limit} more passages not shown.)</p>" if len(rows) > limit else ""
    return f"<table>{head}{''.join(body)}</table>{more}"


def _key_figures(
    res: RunResults, acc: dict | None, alt: runinfo.SourceShare, head: runinfo.SourceShare, gt_xy: np.ndarray | None
) -> list[tuple[str, str]]:
    t = res.t_s
    s = res.summary
    n_lm = len(res.landmarks.get("id", [])) if res.landmarks else 0
    revisits = sum(
        max(0, len(runinfo.passages(res, int(i))) - 1) for i in (res.landmarks.get("id", []) if n_lm else [])
    )
    skipped = int(np.nansum(res.trajectory["skipped"])) if "skipped" in res.trajectory else 0
    fps = s.get("frames_per_second")
    keys = [
        ("frames", f"{len(t)}" + (f" of {s['frames_in_sequence']}" if s.get("frames_in_sequence") else "")),
        ("duration", f"{(t[-1] - t[0]) if len(t) else 0:.1f} s"),
        ("distance (estimate)", f"{runinfo.distance_m(res.xy_m):.2f} m"),
    ]
    if gt_xy is not None:
        keys.append(("distance (truth)", f"{runinfo.distance_m(gt_xy):.2f} m"))
    keys += [
        ("landmarks", str(n_lm)),
        ("revisits", str(revisits)),
        ("processing", f"{fps:.0f} frames/s" if isinstance(fps, (int, float)) and math.isfinite(fps) else "n/a"),
        ("skipped frames", str(skipped)),
    ]
    if acc is not None:
        keys += [
            ("ATE RMSE (SLAM)", _fmt_cm(acc["ate_rmse_m"])),
            ("ATE RMSE (dead reckoning)", _fmt_cm(acc["dr_ate_rmse_m"])),
            ("truth inside 2&sigma;", f"{100 * acc['coverage_2sigma']:.1f} % of frames"),
        ]
    keys += [("altitude from", html.escape(alt.label)), ("heading from", html.escape(head.label))]
    return keys


def _choose_landmarks(res: RunResults, landmarks: list[int] | None) -> list[int]:
    ids = [int(i) for i in res.landmarks.get("id", [])] if res.landmarks else []
    if landmarks:
        missing = [i for i in landmarks if i not in ids]
        if missing:
            from rovslam.errors import InvalidArgumentError

            raise InvalidArgumentError(
                f"--landmarks: no landmark {', '.join(map(str, missing))} in this run (it has ids 0 to {len(ids) - 1})"
            )
        return list(landmarks)
    if not ids:
        return []
    return ([0] if 0 in ids else []) + runinfo.most_revisited(res, 2, exclude=(0,))


def _gallery_section(
    res: RunResults, out: Path, folder: Path, chosen: list[int], seq: Path | None, camera_file: Path | None
) -> str:
    from rovslam.viz.frames import open_frames

    if not chosen:
        return "<h2>Figures 5 and 6: landmark revisits</h2><p>No landmark in this run.</p>"
    views = {lid: gallery.select_views(res, lid) for lid in chosen}
    note = ""
    images: dict[int, np.ndarray] = {}
    try:
        store = open_frames(res.summary, seq, camera_file, res.folder)
        images = store.images(v.frame for vs in views.values() for v in vs)
    except RovslamError as exc:
        saved = (folder / "revisits").is_dir()
        note = f"Frames not available ({exc})" + ("; showing the crops saved by the run." if saved else ".")
    tokens = runinfo.read_tokens(folder)
    if not tokens:
        note = (note + " " if note else "") + "This run recorded no speed tokens (tokens.csv missing)."
    blocks = [
        (lid, gallery.attach_images(views[lid], images, tokens, folder), gallery.read_template(folder, lid))
        for lid in chosen
    ]
    parts = [
        "<h2>Figures 5 and 6: the landmarks at initialisation and at each revisit</h2>",
        "<p>Yellow: the landmark's 32x32 template where it was matched; green: the 16x16 speed tokens "
        "tracked in that frame. Below each view: the template cut at initialisation beside the patch "
        "matched there, with the normalised correlation and the NIS of the update.</p>",
    ]
    if note:
        parts.append(f"<p class='note'>{html.escape(note)}</p>")
    first, rest = blocks[:1], blocks[1:]
    p5 = gallery.plot_gallery(
        first,
        out / f"fig5_landmark_{first[0][0]}.png",
        f"Fig. 5  Camera views when landmark {first[0][0]} is initialised or revisited",
        note,
    )
    parts.append(_img(p5, "Figure 5"))
    if rest:
        p6 = gallery.plot_gallery(
            rest,
            out / "fig6_landmarks.png",
            f"Fig. 6  Camera views of landmark{'s' if len(rest) > 1 else ''} "
            + ", ".join(str(b[0]) for b in rest)
            + " at initialisation and revisits",
            note,
        )
        parts.append(_img(p6, "Figure 6"))
    return "\n".join(parts)


def _mosaic_section(
    folder: Path,
    out: Path,
    seq: Path | None,
    groundtruth: Path | None,
    every: int | None,
    progress: Callable[[int, int], None] | None,
    camera_file: Path | None,
) -> str:
    from rovslam.viz.mosaic import mosaic_of_run

    head = "<h2>Seabed mosaic</h2>"
    try:
        res = read_results(folder)
        n = len(res.t_s)
        k = every or max(1, n // 1500)
        est = mosaic_of_run(folder, out / "mosaic.png", seq=seq, every=k, progress=progress, camera_file=camera_file)
        truth = None
        if groundtruth is not None:
            truth = mosaic_of_run(
                folder,
                out / "mosaic_truth.png",
                seq=seq,
                every=k,
                groundtruth=groundtruth,
                grid=est.mosaic.grid,
                progress=progress,
                camera_file=camera_file,
            )
    except RovslamError as exc:
        return head + f"<p class='note'>No mosaic: {html.escape(str(exc))}</p>"
    g = est.mosaic.grid
    text = (
        f"<p>Every {k}{'st' if k == 1 else 'th'} frame laid on the seabed by its pose, altitude and camera model "
        f"({est.mosaic.frames_used} frames, {g.mm_per_px:g} mm/px, north up). Blue: the path; red: the landmarks. "
        f"World files (<code>.pgw</code>, metres in the run's frame, x north / y east) are beside the PNGs.</p>"
    )
    if truth is None:
        return head + text + _img(_jpeg(est.png), "mosaic", "laid by the estimate")
    return (
        head + text + "<p>Left: laid by the estimate; right: by the ground truth, on the same pixel grid. "
        "Where they differ, the navigation error shows as a shift or a blur.</p><div class='pair'>"
        + _img(_jpeg(est.png), "mosaic (estimate)", "estimate")
        + _img(_jpeg(truth.png), "mosaic (truth)", "ground truth")
        + "</div>"
    )


def _jpeg(png: Path, quality: int = 88) -> Path:
    """A JPEG copy of a large PNG for embedding (keeps the HTML mailable); the PNG stays beside it."""
    import cv2

    img = cv2.imread(str(png), cv2.IMREAD_COLOR)
    jpg = png.with_suffix(".jpg")
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])  # type: ignore[arg-type]
    if ok:
        atomic_write_bytes(jpg, buf.tobytes(), "the report's mosaic")
    return jpg


def fig2_caption(res: RunResults, alt: runinfo.SourceShare) -> str:
    """Fig. 2's caption: where the altitude, hence the speeds' scale, came from."""
    words, assumed = plots.altitude_words(res, alt)
    if assumed:
        text = (
            f"Altitude {words} ({alt.label}): the speeds and positions scale with it; "
            "no laser or altimeter measured it on this run."
        )
    else:
        text = f"Altitude from {words} ({alt.label}); the speeds are the optical correlation scaled by it."
    return html.escape(text)


NEES_LOW = 0.1  # mean NEES (2 dof) below this: bounds far wider than the error
NEES_HIGH = 6.0  # above this (3 per degree of freedom): bounds narrower than the error


def nees_note(acc: dict | None) -> str:
    """One sentence on what a mean NEES far from 2 (2 dof) means; "" without a truth or when near 2."""
    if not acc or not math.isfinite(acc.get("nees_mean", math.nan)):
        return ""
    nees = acc["nees_mean"]
    ratio = math.sqrt(2.0 / nees) if nees > 0 else math.inf
    if nees < NEES_LOW:
        return (
            f"Mean NEES {nees:.3f} (2 for bounds that match the error): the filter's bounds are about "
            f"{ratio:.0f} times wider than this dive's error, because they allow for lasting errors "
            "(compass drift, an altitude offset, a speed bias) that this dive did not have."
        )
    if nees > NEES_HIGH:
        return (
            f"Mean NEES {nees:.1f} (2 for bounds that match the error): the filter's bounds are about "
            f"{1 / ratio:.1f} times narrower than this dive's error, so it is more confident than it should be."
        )
    return ""


def config_differences(text: str) -> list[tuple[str, object]]:
    """``(table.key, value)`` of the settings of a config.toml text that differ from the defaults
    (a key the defaults do not know counts as differing); raises ValueError for text that is not TOML."""
    import tomllib

    from rovslam.config import RunConfig, to_dict

    def flat(d: dict, prefix: str = "") -> dict[str, object]:
        out: dict[str, object] = {}
        for k, v in d.items():
            if isinstance(v, dict):
                out.update(flat(v, f"{prefix}{k}."))
            else:
                out[f"{prefix}{k}"] = list(v) if isinstance(v, tuple) else v
        return out

    try:
        given = flat(tomllib.loads(text))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(str(exc)) from None
    defaults = flat(to_dict(RunConfig()))
    return [(k, v) for k, v in given.items() if k not in defaults or defaults[k] != v]


def _toml_lines(items: list[tuple[str, object]]) -> str:
    """``(table.key, value)`` pairs as TOML text, one ``[table]`` header per table."""
    import json

    lines: list[str] = []
    table: str | None = None
    for name, value in items:
        tab, _, key = name.rpartition(".")
        if tab != table:
            lines += ([""] if lines else []) + ([f"[{tab}]"] if tab else [])
            table = tab
        lines.append(f"{key} = {json.dumps(value)}")
    return "\n".join(lines)


def _config_body(text: str) -> str:
    """The settings that differ from the defaults, collapsed in a <details> element."""
    if not text:
        return "<p>Configuration not recorded.</p>"
    try:
        diff = config_differences(text)
    except ValueError:
        diff = None
    others = "All other settings at their defaults"
    if diff is None:
        shown, summary, others = text, "the configuration file (not readable as settings)", "Not compared"
    elif not diff:
        shown, summary, others = "", "every setting at its default", "All settings at their defaults"
    else:
        shown = _toml_lines(diff)
        summary = f"{len(diff)} setting{'s differ' if len(diff) != 1 else ' differs'} from the defaults"
    pre = f"<pre>{html.escape(shown)}</pre>" if shown else ""
    return (
        f"<details><summary>{html.escape(summary)}</summary>{pre}"
        f"<p>{others}; the full file: <code>config.toml</code>.</p></details>"
    )


def _config_html(folder: Path, res: RunResults) -> str:
    cfg = folder / "config.toml"
    text = cfg.read_text(encoding="utf-8") if cfg.is_file() else ""
    if not text and isinstance(res.summary.get("config"), dict):
        import tomli_w

        text = tomli_w.dumps(res.summary["config"])
    sw = res.summary.get("software")
    sw = sw if isinstance(sw, dict) else {}  # a summary.json edited by hand or from another tool
    meta = (
        f"<p>rovslam {html.escape(str(sw.get('version', '?')))}; sequence "
        f"<code>{html.escape(str(res.summary.get('sequence', '?')))}</code>.</p>"
    )
    return "<h2>Configuration of the run</h2>" + meta + _config_body(text)


def write_report(
    results_dir: str | Path,
    groundtruth: str | Path | None = None,
    seq: str | Path | None = None,
    landmarks: list[int] | None = None,
    mosaic: bool = True,
    mosaic_every: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    camera_file: str | Path | None = None,
) -> Path:
    """Write ``results_dir/report/`` (PNGs + one self-contained index.html) and return the HTML path.

    ``seq`` overrides the sequence (or video) named in summary.json for the gallery and the
    mosaic (``camera_file`` the camera of a video run); ``landmarks`` chooses the gallery's landmarks (default: 0 and the two most revisited).
    """
    folder = Path(results_dir)
    res = read_results(folder)
    if len(res.t_s) == 0:
        from rovslam.errors import ResultsFormatError

        raise ResultsFormatError(f"{folder / 'trajectory.csv'}: no frame; nothing to report.")
    out = _report_folder(folder)
    seq_path = Path(seq) if seq is not None else None
    cam_path = Path(camera_file) if camera_file is not None else None
    chosen = _choose_landmarks(res, landmarks)
    gt_xy, acc, notes = _truth(res, groundtruth)
    alt = runinfo.altitude_sources(res)
    head = runinfo.heading_source(res, _frames_source(res, seq_path))
    rep = Report(f"rovslam report: {res.summary.get('sequence_name', folder.name)}")
    rep.keys = _key_figures(res, acc, alt, head, gt_xy)
    rep.warnings = _warnings(res, alt, head) + notes
    figs = [
        ("Figure 2", plots.plot_altitude_speed(res, out / "altitude_speed.png", alt), fig2_caption(res, alt)),
        ("Figure 3", plots.plot_position(res, out / "position.png", gt_xy), nees_note(acc)),
        ("Figure 4", plots.plot_map(res, out / "map.png", gt_xy), ""),
    ]
    rep.sections.append("<h2>Figures 2 to 4</h2>" + "".join(_img(p, name, cap) for name, p, cap in figs))
    rep.sections.append(_feature_reference_section(folder, out))
    rep.sections.append(_gallery_section(res, out, folder, chosen, seq_path, cam_path))
    t1_id = chosen[0] if chosen else 0
    rep.sections.append(
        f"<h2>Table 1: vehicle position at each passage over landmark {t1_id}</h2>"
        "<p>Displacement since the landmark was initialised, as in the paper.</p>"
        + _table1_html(table1(res, gt_xy, t1_id), t1_id)
    )
    if mosaic:
        rep.sections.append(
            _mosaic_section(
                folder,
                out,
                seq_path,
                Path(groundtruth) if gt_xy is not None else None,  # type: ignore[arg-type]
                mosaic_every,
                progress,
                cam_path,
            )
        )
    rep.sections.append(_config_html(folder, res))
    path = out / "index.html"
    atomic_write_text(path, render_html(rep), "the report")
    return path


def _feature_reference_section(folder: Path, out: Path) -> str:
    """The feature reference's figure when ``eval.json`` has a ``feature_reference`` block, else nothing."""
    block = runinfo.read_eval_json(folder / "eval.json").get("feature_reference")
    if not isinstance(block, dict):
        return ""
    from rovslam.viz.feature_plot import feature_reference_caption, plot_feature_reference

    png = plot_feature_reference(block, out / "feature_reference.png")
    if png is None:
        return "<h2>Feature reference</h2><p>No frame pair could be compared with the feature motion.</p>"
    caption = (
        feature_reference_caption(block) + ". Each frame pair's token motion against the feature motion of the "
        "same frames (rovslam eval --reference features); below, how far each pair is from agreeing."
    )
    return "<h2>Feature reference</h2>" + _img(png, "feature reference", html.escape(caption))


def _report_folder(folder: Path) -> Path:
    """``folder/report``, created if needed, or OutputError when something else (a file, a link) is in its place."""
    out = folder / "report"
    if out.exists() and not out.is_dir():
        from rovslam.errors import OutputError
        from rovslam.io.output import file_kind

        kind = "a file" if out.is_file() else file_kind(out.stat().st_mode)
        raise OutputError(
            f"{out}: is {kind}, where the report's folder goes; move or delete it, then run the report again."
        )
    check_output_folder(out, "the report")  # a link to nothing is refused too
    with output_errors(out, "cannot create the folder"):
        out.mkdir(exist_ok=True)
    return out


def _truth(res: RunResults, groundtruth: str | Path | None) -> tuple[np.ndarray | None, dict | None, list[str]]:
    """(the truth's (N, 2) positions at the run's frames in the run's frame, the accuracy figures, notes for the
    reader); (None, None, []) without a ground truth, (None, None, [why]) when its times do not match the run's."""
    if groundtruth is None:
        return None, None, []
    from rovslam.io.sequence import read_groundtruth

    gt = read_groundtruth(groundtruth)
    gt_xy = runinfo.truth_at(res, gt.t_s, gt.xy_m)
    if gt_xy is not None:  # a run without compass: the truth in its frame (its first heading)
        from rovslam.eval.metrics import run_frame_turn_rad, to_run_frame

        first_heading_rad = runinfo.truth_at(res, gt.t_s, gt.heading_rad)[0]  # type: ignore[index]
        gt_xy = to_run_frame(gt_xy, run_frame_turn_rad(res, float(first_heading_rad)))
    if gt_xy is None:
        return None, None, [f"{groundtruth}: its times do not match the run's frames; accuracy figures left out."]
    return gt_xy, runinfo.accuracy(res, gt_xy), []


def _warnings(res: RunResults, alt: runinfo.SourceShare, head: runinfo.SourceShare) -> list[str]:
    """The report's warnings: an assumed altitude or heading, an interrupted run, what the run noticed."""
    warnings = []
    if alt.assumed:
        warnings.append(
            f"Altitude NOT MEASURED in part or all of the run: {alt.label}. Speeds and positions scale "
            "with the assumed value."
        )
    if head.assumed:
        warnings.append(f"Heading: {head.label}.")
    if res.summary.get("interrupted"):
        warnings.append("The run was interrupted: these are the frames processed before it stopped.")
    for key in ("sunlight", "map_use"):  # what the run noticed about the seabed's appearance
        part = res.summary.get(key)
        if isinstance(part, dict):
            warnings += [w[:1].upper() + w[1:] + "." for w in part.get("warnings", []) if isinstance(w, str)]
    return warnings


def _frames_source(res: RunResults, seq: Path | None) -> Path | None:
    from rovslam.viz.frames import source_path

    return source_path(res.summary, seq)


def render_html(rep: Report) -> str:
    """The report as one HTML document (images already inlined in the sections)."""
    keys = "".join(f"<div class='key'>{k}<b>{v}</b></div>" for k, v in rep.keys)
    warns = "".join(f"<div class='warn'>&#9888; {html.escape(w)}</div>" for w in rep.warnings)
    return "\n".join(
        [
            "<!doctype html><html lang='en'><meta charset='utf-8'>",
            f"<title>{html.escape(rep.title)}</title><style>{_CSS}</style><body>",
            f"<h1>{html.escape(rep.title)}</h1>",
            f"<div class='keys'>{keys}</div>",
            warns,
            *rep.sections,
            "</body></html>",
        ]
    )
