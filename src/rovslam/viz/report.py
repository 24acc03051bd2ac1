"""A self-contained HTML report of a run: the paper's figures, the evaluation, the landmark templates."""

from __future__ import annotations

import html
import json
from pathlib import Path

from rovslam.io.results import read_results
from rovslam.viz import plots


def write_report(results_dir: str | Path, groundtruth: str | Path | None = None) -> Path:
    """Write ``results_dir/report/`` (PNGs + index.html) and return the HTML path."""
    from rovslam.eval.metrics import align_by_time, evaluate
    from rovslam.io.sequence import read_groundtruth

    res = read_results(results_dir)
    out = Path(results_dir) / "report"
    out.mkdir(exist_ok=True)
    gt_xy = figures = None
    if groundtruth is not None:
        gt = read_groundtruth(groundtruth)
        gt_xy = gt.xy_m[align_by_time(res.t_s, gt.t_s)]
        figures = evaluate(res, gt)
    imgs = [
        plots.plot_altitude_speed(res, out / "altitude_speed.png"),
        plots.plot_position(res, out / "position.png", gt_xy),
        plots.plot_map(res, out / "map.png", gt_xy),
    ]
    if gt_xy is not None:
        imgs.append(plots.plot_errors(res, out / "errors.png", gt_xy))
    parts = [
        "<!doctype html><meta charset='utf-8'><title>rovslam report</title>",
        "<style>body{font-family:sans-serif;max-width:1000px;margin:auto}img{max-width:100%}"
        "td,th{padding:2px 8px;text-align:right}table{border-collapse:collapse}"
        "tr:nth-child(even){background:#f3f3f3}</style>",
        f"<h1>rovslam report: {html.escape(str(res.summary.get('sequence_name', '')))}</h1>",
        f"<p>{len(res.t_s)} frames, {len(res.landmarks.get('id', []))} landmarks, "
        f"{res.summary.get('frames_per_second', float('nan')):.0f} frames/s"
        f"{' (interrupted run)' if res.summary.get('interrupted') else ''}.</p>",
    ]
    if figures is not None:
        s, d, c = figures.slam, figures.dead_reckoning, figures.consistency
        rows = [
            ("ATE RMSE [cm]", s.ate_rmse_m * 100, d.ate_rmse_m * 100),
            ("ATE max [cm]", s.ate_max_m * 100, d.ate_max_m * 100),
            ("final error [cm]", s.final_error_m * 100, d.final_error_m * 100),
            ("final error / distance [%]", s.final_error_pct, d.final_error_pct),
        ]
        parts.append("<h2>Accuracy</h2><table><tr><th></th><th>SLAM</th><th>dead reckoning</th></tr>")
        parts += [f"<tr><td>{n}</td><td>{_num(a)}</td><td>{_num(b)}</td></tr>" for n, a, b in rows]
        parts.append(
            f"</table><p>Distance travelled {s.distance_m:.2f} m; truth inside the 2-sigma ellipse in "
            f"{100 * c.coverage_2sigma:.1f} % of frames; mean NEES {c.nees_mean:.2f} (2 dof).</p>"
        )
        if figures.table1_landmark0:
            parts.append("<h2>Table 1: position while tracking landmark 0</h2><table><tr><th>time [s]</th>"
                         "<th>x&#770; [m]</th><th>y&#770; [m]</th><th>x<sub>GT</sub></th><th>y<sub>GT</sub></th></tr>")
            for r in figures.table1_landmark0:
                parts.append(
                    f"<tr><td>{r.t_s:.1f}</td><td>{r.x_est_m:.3f}</td><td>{r.y_est_m:.3f}</td>"
                    f"<td>{r.x_gt_m:.3f}</td><td>{r.y_gt_m:.3f}</td></tr>"
                )
            parts.append("</table>")
        (out / "eval.json").write_text(json.dumps(figures.to_dict(), indent=2), encoding="utf-8")
    parts.append("<h2>Figures</h2>")
    parts += [f"<p><img src='{p.name}'></p>" for p in imgs]
    lm_dir = Path(results_dir) / "landmarks"
    templates = sorted(lm_dir.glob("*.png"), key=lambda p: int(p.stem))[:48] if lm_dir.is_dir() else []
    if templates:
        parts.append("<h2>Landmark templates</h2><p>")
        parts += [
            f"<span style='display:inline-block;text-align:center;margin:3px'><img src='../landmarks/{p.name}' "
            f"width=64 style='image-rendering:pixelated'><br>{p.stem}</span>"
            for p in templates
        ]
        parts.append("</p>")
    path = out / "index.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def _num(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"
