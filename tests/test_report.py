"""The HTML report: self-contained, the paper's figures, the revisit gallery, honest about its sources."""

from __future__ import annotations

import base64
import csv
import dataclasses
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.io.run_results import read_results
from rovslam.io.sequence import open_sequence, read_groundtruth
from rovslam.runner import run_sequence
from rovslam.sim import simulate
from rovslam.viz import gallery, plots, runinfo
from rovslam.viz.report import config_differences, nees_note, table1, write_report

FRAMES = 280  # landmark 0 is first revisited at 39.8 s (frame 199) in portofino seed 0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    simulate("portofino-short", root / "seq", frames=FRAMES, seed=0)
    run_sequence(root / "seq", root / "out")
    return root


class _Images(HTMLParser):
    def __init__(self):
        super().__init__()
        self.srcs: list[str] = []
        self.links: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.srcs.append(a.get("src", ""))
        for key in ("href", "src"):
            if tag in ("link", "script", "a", "iframe") and a.get(key):
                self.links.append(a[key])


def _decode(uri: str) -> np.ndarray:
    head, data = uri.split(",", 1)
    assert re.fullmatch(r"data:image/(png|jpeg);base64", head), head
    img = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    return img


def test_report_is_one_self_contained_file_with_every_figure(run):
    out, seq = run / "out", run / "seq"
    html_path = write_report(out, seq / "groundtruth.csv")
    text = html_path.read_text(encoding="utf-8")
    p = _Images()
    p.feed(text)
    assert p.links == []  # nothing linked: no stylesheet, script or file
    assert "../landmarks" not in text
    imgs = [_decode(s) for s in p.srcs]
    # Figures 2, 3, 4, Figures 5 and 6, and the two mosaics; no unnumbered figure repeating Fig. 3's error panels.
    assert len(imgs) == 7
    assert not (out / "report" / "errors.png").exists() and "Position error" not in text
    assert all(min(i.shape[:2]) > 200 for i in imgs)
    for name in (
        "altitude_speed.png",
        "position.png",
        "map.png",
        "fig5_landmark_0.png",
        "fig6_landmarks.png",
        "mosaic.png",
        "mosaic.pgw",
        "mosaic_truth.png",
        "mosaic_truth.pgw",
    ):
        assert (out / "report" / name).stat().st_size > 50
    # A copy of the HTML alone, elsewhere, holds the same pictures.
    moved = run / "elsewhere.html"
    shutil.copy(html_path, moved)
    assert moved.read_text(encoding="utf-8") == text
    # Key figures: the report's ATE and coverage are those of the result files against the truth.
    res = read_results(out)
    gt = read_groundtruth(seq / "groundtruth.csv")
    acc = runinfo.accuracy(res, runinfo.truth_at(res, gt.t_s, gt.xy_m))
    assert f"{100 * acc['ate_rmse_m']:.2f} cm" in text
    assert f"{100 * acc['coverage_2sigma']:.1f} % of frames" in text
    assert f"{FRAMES} of {FRAMES}" in text
    assert "laser+sonar (100 %)" in text and "compass" in text
    assert "NOT MEASURED" not in text


def test_table1_and_gallery_show_each_passage_with_its_tokens_and_saved_crop(run):
    out, seq = run / "out", run / "seq"
    res = read_results(out)
    gt = read_groundtruth(seq / "groundtruth.csv")
    rows = table1(res, runinfo.truth_at(res, gt.t_s, gt.xy_m), 0)
    assert len(rows) >= 2 and rows[0]["x_est_m"] == 0.0 and rows[0]["y_gt_m"] == 0.0
    assert rows[1]["t_s"] > 30.0
    for r in rows:  # the estimate and the truth agree within 1 cm (the filter's bound is below that)
        assert abs(r["x_est_m"] - r["x_gt_m"]) < 0.01 and abs(r["y_est_m"] - r["y_gt_m"]) < 0.01
    views = gallery.select_views(res, 0)
    assert views[0].kind == "init" and views[1].kind == "track" and views[1].score >= 0.89
    s = open_sequence(seq)
    images = {i: img for i, img in zip(range(FRAMES), (f.image for f in s.frames()))}
    tokens = runinfo.read_tokens(out)
    full = gallery.attach_images(views, images, tokens, out)
    tracked = {int(k): int(v) for k, v in zip(range(FRAMES), res.trajectory["tokens_tracked"])}
    for v in full:
        assert v.image is not None
        assert len(v.tokens_uv_px) == tracked[v.frame]  # the tokens drawn are those the run tracked there
        # the run saved the crop around the match at each passage, from the very frame
        crop = cv2.cvtColor(cv2.imread(str(out / "revisits" / "0" / f"{v.frame}.png")), cv2.COLOR_BGR2RGB)
        expect = cv2.getRectSubPix(images[v.frame], (64, 64), (float(v.uv_px[0]), float(v.uv_px[1])))
        assert np.array_equal(crop, expect)
    assert len(full[1].tokens_uv_px) >= 4
    # With the frames gone, the saved crops stand in.
    crops = gallery.attach_images(views, {}, tokens, out)
    assert all(v.image is None and v.crop is not None and v.crop.shape == (64, 64, 3) for v in crops)


def test_assumed_altitude_is_said_and_a_missing_sequence_is_reported_not_fatal(run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(run / "out", out)
    traj = out / "trajectory.csv"
    with traj.open(newline="") as fh:
        rows = list(csv.reader(fh))
    col = rows[0].index("altitude_source")
    for r in rows[1:]:
        r[col] = "fixed"
    with traj.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    text = write_report(out, seq=tmp_path / "gone", mosaic=False).read_text(encoding="utf-8")
    assert "NOT MEASURED" in text and "ASSUMED constant" in text
    assert "laser+sonar" not in text
    assert "Frames not available" in text and "crops saved by the run" in text
    assert "2&sigma; x [cm]" in text  # Table 1 without a truth: the estimate and its bounds


def test_report_cli_checks_landmark_ids(run):
    res = CliRunner().invoke(app, ["report", str(run / "out"), "--landmarks", "0,x", "--no-mosaic", "-q"])
    assert res.exit_code == 2 and "--landmarks" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(app, ["report", str(run / "out"), "--landmarks", "0,500", "--no-mosaic", "-q"])
    assert res.exit_code == 2 and "no landmark 500" in res.output


_PROBE = """<script>
window.addEventListener('load', () => {
  const imgs = Array.from(document.images);
  document.body.setAttribute('data-probe', imgs.map(i => i.complete + ':' + i.naturalWidth + 'x' + i.naturalHeight).join(';'));
});
</script>"""


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.slow
def test_report_displays_every_figure_in_headless_chromium(run, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install -y chromium)")
    html_path = write_report(run / "out", run / "seq" / "groundtruth.csv")
    probe = tmp_path / "probe.html"
    probe.write_text(html_path.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--no-first-run",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--virtual-time-budget=10000",
    ]
    dom = subprocess.run([browser, *flags, "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=180)
    m = re.search(r'data-probe="([^"]*)"', dom.stdout)
    assert m, dom.stderr[-2000:]
    shown = m.group(1).split(";")
    assert len(shown) == 8
    for s in shown:
        complete, size = s.split(":")
        w, h = (int(v) for v in size.split("x"))
        assert complete == "true" and w > 200 and h > 200, shown
    shot = tmp_path / "shot.png"
    subprocess.run(
        [browser, *flags, "--window-size=1200,2400", f"--screenshot={shot}", html_path.as_uri()],
        capture_output=True,
        timeout=180,
    )
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[:2] == (2400, 1200)
    assert float(img.std()) > 20  # figures drawn, not a blank page


def _position_res_truth(run):
    res = read_results(run / "out")
    gt = read_groundtruth(run / "seq" / "groundtruth.csv")
    return res, runinfo.truth_at(res, gt.t_s, gt.xy_m)


def test_fig3_legends_cover_no_plotted_line(run):
    res, gt_xy = _position_res_truth(run)
    for truth in (gt_xy, None):
        fig = plots.position_figure(res, truth)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        legends = [a.get_legend() for a in fig.axes if a.get_legend() is not None]
        assert len(legends) >= 2
        for leg in legends:
            box = leg.get_window_extent(renderer)
            for a in fig.axes:
                for line in a.get_lines():
                    xy = line.get_xydata()
                    pts = a.transData.transform(xy[np.all(np.isfinite(xy), axis=1)])
                    inside = (
                        (pts[:, 0] >= box.x0) & (pts[:, 0] <= box.x1) & (pts[:, 1] >= box.y0) & (pts[:, 1] <= box.y1)
                    )
                    assert not inside.any(), (line.get_label(), int(inside.sum()))
        plots.pyplot().close(fig)


def _band_label(fig) -> str:
    labels = fig.axes[0].get_legend_handles_labels()[1]
    return next(lb for lb in labels if lb.startswith("+-2 sigma"))


def test_thin_band_note_only_when_the_band_is_too_thin_to_see(run):
    # Numbers: a band 0.5 % of the range is too thin, 2 % is not.
    t = np.linspace(0, 1, 101)
    curve = 10 * t
    assert plots.band_too_thin(curve - 0.025, curve + 0.025, [curve])
    assert not plots.band_too_thin(curve - 0.1, curve + 0.1, [curve])
    res, gt_xy = _position_res_truth(run)
    sd = plots.sigma_m(res)
    width = 4 * np.median(sd, axis=0)
    span = np.ptp(res.xy_m, axis=0)
    assert np.all(width > 0.01 * span)  # this dive's band is plain to see on the position panels
    fig = plots.position_figure(res, gt_xy)
    assert _band_label(fig) == "+-2 sigma"
    plots.pyplot().close(fig)
    traj = dict(res.trajectory)
    traj["var_x_m2"] = traj["var_x_m2"] * 1e-4  # sigma / 100: a band far below 1 % of the range
    traj["var_y_m2"] = traj["var_y_m2"] * 1e-4
    thin = dataclasses.replace(res, trajectory=traj)
    fig = plots.position_figure(thin, gt_xy)
    assert _band_label(fig) == "+-2 sigma (see below, too thin here)"
    plots.pyplot().close(fig)


def test_fig2_title_and_caption_follow_the_altitude_source(run, tmp_path):
    res = read_results(run / "out")
    title = plots.altitude_speed_title(res, runinfo.altitude_sources(res))
    assert "laser triangulation" in title and "ASSUMED" not in title
    out = tmp_path / "out"
    shutil.copytree(run / "out", out)
    summary = json.loads((out / "summary.json").read_text())
    n = len(res.t_s)
    summary["sources"]["altitude"] = {
        "source": "assumed constant",
        "frames": {"assumed constant": n},
        "detail": "assumed constant: 1.8 m",
    }
    (out / "summary.json").write_text(json.dumps(summary))
    traj = out / "trajectory.csv"
    with traj.open(newline="") as fh:
        rows = list(csv.reader(fh))
    col = rows[0].index("altitude_source")
    for r in rows[1:]:
        r[col] = "fixed"
    with traj.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    res2 = read_results(out)
    fig = plots.altitude_speed_figure(res2, runinfo.altitude_sources(res2))
    title = fig._suptitle.get_text()
    plots.pyplot().close(fig)
    assert "ASSUMED, not measured" in title and "laser" not in title.lower()
    text = write_report(out, mosaic=False).read_text(encoding="utf-8")
    caption = re.search(r"alt='Figure 2'><figcaption>([^<]*)", text).group(1)
    assert "ASSUMED, not measured" in caption and "laser triangulation" not in caption


def _report_copy(run, tmp_path) -> tuple[Path, str]:
    """A copy of the run's results and the text of its report (with the truth, no mosaic)."""
    out = tmp_path / "out"
    shutil.copytree(run / "out", out, ignore=shutil.ignore_patterns("report"))
    return out, write_report(out, run / "seq" / "groundtruth.csv", mosaic=False).read_text(encoding="utf-8")


def test_config_shows_only_the_settings_that_differ_collapsed(run, tmp_path):
    out, text = _report_copy(run, tmp_path)
    section = text[text.index("<h2>Configuration of the run</h2>") :]
    assert "<details><summary>every setting at its default</summary>" in section
    assert "the full file: <code>config.toml</code>" in section and "[bandpass]" not in section
    cfg = (out / "config.toml").read_text()
    assert "max_side_px = 480" in cfg
    (out / "config.toml").write_text(cfg.replace("max_side_px = 480", "max_side_px = 640"))
    assert config_differences((out / "config.toml").read_text()) == [("processing.max_side_px", 640)]
    text = write_report(out, mosaic=False).read_text(encoding="utf-8")
    section = text[text.index("<h2>Configuration of the run</h2>") :]
    assert "<details><summary>1 setting differs from the defaults</summary>" in section
    assert "<pre>[processing]\nmax_side_px = 640</pre>" in section
    assert "All other settings at their defaults; the full file: <code>config.toml</code>" in section
    assert section.count("\n") < 12  # not the 150-line file


def test_a_mean_nees_far_from_two_is_explained_in_one_sentence(run, tmp_path):
    assert nees_note(None) == "" and nees_note({"nees_mean": 2.0}) == "" and nees_note({"nees_mean": 0.5}) == ""
    low = nees_note({"nees_mean": 0.02})
    assert "10 times wider" in low and "did not have" in low and low.count(". ") == 0
    high = nees_note({"nees_mean": 18.0})
    assert "3.0 times narrower" in high
    res, gt_xy = _position_res_truth(run)
    nees = runinfo.accuracy(res, gt_xy)["nees_mean"]
    _, text = _report_copy(run, tmp_path)
    if nees < 0.1:
        assert f"Mean NEES {nees:.3f}" in text and "wider than this dive" in text
    else:
        assert "Mean NEES" not in text
