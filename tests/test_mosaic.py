"""The seabed mosaic: frames laid by the true poses land where the simulator's seabed is; world file exact."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rovslam.camera import Camera
from rovslam.errors import InvalidArgumentError
from rovslam.io.sequence import read_groundtruth
from rovslam.sim import simulate
from rovslam.sim.world import World
from rovslam.viz.frames import open_frames
from rovslam.viz.mosaic import (
    Mosaic,
    MosaicGrid,
    Poses,
    TiledAccumulator,
    build_mosaic,
    decorate,
    landmark_labels,
    plan_grid,
    read_world_file,
    truth_poses,
    write_mosaic,
)

MM_PER_PX = 1.0


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    root = tmp_path_factory.mktemp("mosaic")
    simulate("portofino-short", root / "seq", frames=40, seed=3)
    return root


def _seabed_under(pgw: np.ndarray, cols: np.ndarray, rows: np.ndarray, seed: int) -> np.ndarray:
    """(h, w) float32 grey of the simulator's seabed albedo at mosaic pixels, through the world file."""
    seabed = World.procedural(seed).seabed
    east = pgw[0, 0] * cols + pgw[0, 1] * rows + pgw[0, 2]
    north = pgw[1, 0] * cols + pgw[1, 1] * rows + pgw[1, 2]
    ti, tj = north / seabed.texel_m, east / seabed.texel_m  # texel (i, j) lies at x = i t (north), y = j t (east)
    r0, c0 = int(np.floor(ti.min())) - 8, int(np.floor(tj.min())) - 8
    region = seabed.region(r0, c0, int(np.ceil(ti.max())) - r0 + 16, int(np.ceil(tj.max())) - c0 + 16)
    grey = cv2.cvtColor(region, cv2.COLOR_RGB2GRAY).astype(np.float32)
    grey = cv2.GaussianBlur(grey, (0, 0), 1.0)  # the camera resolves about 1.2 mm: 2.4 texels
    return cv2.remap(grey, (tj - c0).astype(np.float32), (ti - r0).astype(np.float32), cv2.INTER_LINEAR)


def _highpass(a: np.ndarray) -> np.ndarray:
    a = a.astype(np.float32)
    a = cv2.GaussianBlur(a, (0, 0), 0.7) - cv2.GaussianBlur(a, (0, 0), 6.0)
    return (a - a.mean()) / (a.std() + 1e-6)


def test_truth_mosaic_puts_the_seabed_within_a_few_mm_and_the_world_file_maps_pixels_to_metres(dive, tmp_path):
    seq = dive / "seq"
    store = open_frames({"sequence": str(seq)})
    gt = read_groundtruth(seq / "groundtruth.csv")
    poses = truth_poses(gt, np.array([r.t_s for r in store.source.rows]), store.roll_rad, store.pitch_rad)
    assert len(poses.frame) == 40
    mosaic = build_mosaic(store.camera, poses, store.stream, MM_PER_PX)
    assert mosaic.frames_used == 40
    png, pgw_path = write_mosaic(tmp_path / "m.png", decorate(mosaic, gt.xy_m), mosaic.grid)
    pgw = read_world_file(pgw_path)
    # The world file maps pixel centres to (east, north) in metres at the requested scale.
    assert pgw[0, 0] == pytest.approx(MM_PER_PX / 1000) and pgw[1, 1] == pytest.approx(-MM_PER_PX / 1000)
    assert pgw[0, 1] == 0 and pgw[1, 0] == 0
    cr = np.array([[0.0, 0.0], [123.0, 45.0], [mosaic.grid.width_px - 1.0, mosaic.grid.height_px - 1.0]])
    en = (np.column_stack([cr, np.ones(3)]) @ pgw.T)[:, :2]
    np.testing.assert_allclose(en[:, ::-1], mosaic.grid.px_to_world(cr), atol=1e-9)
    # The PNG holds the mosaic pixel for pixel from (0, 0) (the legend band is added below it).
    written = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
    assert written.shape[1] == mosaic.grid.width_px and written.shape[0] > mosaic.grid.height_px
    # Seabed features under three points of the dive: measured shift of the mosaic against the
    # simulator's own seabed at the place the world file names.
    inv = np.linalg.inv(pgw)
    half = 48
    shifts_mm = []
    for k in (0, 20, 39):
        c, r, _ = inv @ np.array([gt.y_m[k], gt.x_m[k], 1.0])
        c, r = int(round(c)), int(round(r))
        win = mosaic.rgb[r - half : r + half, c - half : c + half]
        assert mosaic.covered[r - half : r + half, c - half : c + half].all()
        rows, cols = np.mgrid[r - half : r + half, c - half : c + half].astype(np.float64)
        ref = _highpass(_seabed_under(pgw, cols, rows, seed=3))
        got = _highpass(cv2.cvtColor(win, cv2.COLOR_RGB2GRAY))
        ncc0 = float(np.mean(ref * got))
        ncc_off = float(np.mean(ref[:, 6:] * got[:, :-6]))  # the same seabed 6 mm away does not match
        assert ncc0 > 0.9 and ncc_off < 0.3, (ncc0, ncc_off)
        (dx, dy), resp = cv2.phaseCorrelate(ref, got, cv2.createHanningWindow(ref.shape[::-1], cv2.CV_32F))
        assert resp > 0.1
        shifts_mm.append(np.hypot(dx, dy) * MM_PER_PX)
    assert max(shifts_mm) < 0.5, shifts_mm  # measured: about 0.05 mm


def test_tiles_are_allocated_only_where_frames_land():
    acc = TiledAccumulator(4096, 4096, tile_px=512)
    patch = np.zeros((10, 10, 4), np.float32)
    patch[..., :3] = 100.0 * 2.0
    patch[..., 3] = 2.0
    acc.add(patch, 5, 5)
    acc.add(patch, 4000, 4000)
    acc.add(patch, 507, 100)  # straddles two tiles
    assert len(acc.tiles) == 3
    rgb, covered = acc.image()
    assert covered.sum() == 300
    assert np.all(rgb[covered] == 100)


def test_grid_plan_refuses_a_mosaic_too_large_and_bad_scales():
    cam = Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5)
    poses = Poses(
        np.arange(2), np.array([0.0, 500.0]), np.zeros(2), np.full(2, 1.3), np.zeros(2), np.zeros(2), np.zeros(2)
    )
    with pytest.raises(InvalidArgumentError, match="coarser --mm-per-px"):
        plan_grid(cam, poses, 1.0)
    with pytest.raises(InvalidArgumentError, match="positive"):
        plan_grid(cam, poses, 0.0)
    g = plan_grid(
        cam,
        Poses(
            *(
                a[:1]
                for a in (
                    poses.frame,
                    poses.x_m,
                    poses.y_m,
                    poses.altitude_m,
                    poses.heading_rad,
                    poses.roll_rad,
                    poses.pitch_rad,
                )
            )
        ),
        2.0,
    )
    # the footprint at 1.3 m is about 33 cm x 44 cm: at 2 mm/px, ~164 x ~218 px plus the margin
    assert isinstance(g, MosaicGrid) and 215 <= g.width_px <= 230 and 160 <= g.height_px <= 175


def test_mosaic_command_lays_the_estimate_where_the_truth_lays_the_frames(dive, tmp_path):
    from typer.testing import CliRunner

    from rovslam.cli import app
    from rovslam.runner import run_sequence
    from rovslam.viz.mosaic import mosaic_of_run

    out = tmp_path / "out"
    run_sequence(dive / "seq", out)
    runner = CliRunner()
    res = runner.invoke(app, ["mosaic", str(out), "--mm-per-px", "1", "-q"])
    assert res.exit_code == 0, res.output
    assert (out / "mosaic.png").is_file() and (out / "mosaic.pgw").is_file() and "1 mm/px, 40 frames" in res.output
    bad = runner.invoke(app, ["mosaic", str(out), "--every", "0"])
    assert bad.exit_code == 2 and "--every" in bad.output and "Traceback" not in bad.output
    gone = runner.invoke(app, ["mosaic", str(out), "--seq", str(tmp_path / "nowhere")])
    assert gone.exit_code == 2 and "--seq" in gone.output
    est = mosaic_of_run(out, tmp_path / "e.png", mm_per_px=1.0, overlay=False).mosaic
    tru = mosaic_of_run(
        out, tmp_path / "t.png", groundtruth=dive / "seq" / "groundtruth.csv", grid=est.grid, overlay=False
    ).mosaic
    both = est.covered & tru.covered
    assert both.sum() > 0.95 * est.covered.sum()  # the same seabed is covered
    a = _highpass(cv2.cvtColor(est.rgb, cv2.COLOR_RGB2GRAY))[both]
    b = _highpass(cv2.cvtColor(tru.rgb, cv2.COLOR_RGB2GRAY))[both]
    # the estimate is within a millimetre of the truth on this short dive: the two mosaics agree
    assert float(np.corrcoef(a, b)[0, 1]) > 0.9


def test_landmark_ids_never_overlap_and_a_lone_one_sits_above_right_of_its_cross():
    crowd = np.array([[100.0, 100.0], [101.0, 100.0], [100.0, 101.0], [102.0, 102.0], [99.0, 100.0], [100.0, 99.0]])
    points = np.vstack([crowd, [[20.0, 150.0]]])
    texts = [str(i) for i in range(len(crowd))] + ["17"]
    labels = landmark_labels(points, texts, (200, 200))
    boxes = []
    for text, (u, v), _ in labels:
        (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.35, 1)
        boxes.append((u, v - h, u + w, v))  # putText's origin is the text's bottom-left corner
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]), (a, b)
    for (u0, v0, u1, v1), (pu, pv) in zip(boxes, points):
        assert 0 <= u0 and u1 <= 200 and 0 <= v0 and v1 <= 200  # inside the mosaic
        assert max(u0 - pu, pu - u1, v0 - pv, pv - v1) < 40  # near its cross
    text, (u, v), leader = labels[-1]
    assert leader is None and 20 < u < 30 and 140 < v < 150  # above and to the right of (20, 150)
    assert sum(leader is not None for _, _, leader in labels) >= 1  # the crowd's later ids point back


def test_landmarks_a_centimetre_apart_get_their_ids_on_separate_rows():
    grid = MosaicGrid(x_top_m=0.5, y_left_m=-0.5, mm_per_px=5.0, width_px=200, height_px=200)
    blank = Mosaic(
        rgb=np.full((200, 200, 3), 255, np.uint8), covered=np.ones((200, 200), bool), grid=grid, frames_used=1, tiles=1
    )
    lms = {"id": np.array([1, 2]), "x_m": np.array([0.0, 0.001]), "y_m": np.array([0.0, 0.002])}
    img = decorate(blank, None, lms)[:200]
    red = (img[:, :, 0] > 150) & (img[:, :, 1] < 120)
    rows = np.flatnonzero(red[:, 106:125].any(axis=1))  # the labels' columns, right of the 9 px markers
    bands = np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1)
    assert len(bands) == 2, bands  # two separate rows of text, not one id printed over the other


def _blank(width_px: int, height_px: int = 120) -> Mosaic:
    grid = MosaicGrid(x_top_m=0.5, y_left_m=-0.5, mm_per_px=1.3, width_px=width_px, height_px=height_px)
    rgb = np.full((height_px, width_px, 3), 255, np.uint8)
    return Mosaic(rgb=rgb, covered=np.ones((height_px, width_px), bool), grid=grid, frames_used=1, tiles=1)


def _scale_label_height_px(width_px: int) -> int:
    """Rows of ink of the scale bar's length ("20 cm"...), measured in the band under a blank mosaic."""
    img = decorate(_blank(width_px), None, None)
    band = img[120:].min(axis=2) < 128
    bar_rows = np.flatnonzero(band[:, : width_px // 8].sum(axis=1) > width_px // 16)  # the solid first bar segment
    below = band[bar_rows.max() + 2 :, : width_px // 8]
    rows = np.flatnonzero(below.any(axis=1))
    return int(rows.max() - rows.min() + 1)


def test_scale_text_is_readable_and_grows_with_the_mosaic():
    small = _scale_label_height_px(630)  # the size of a short dive's mosaic
    assert small >= 12, small  # was 8 px of ink (font scale 0.4)
    big = _scale_label_height_px(3200)
    assert 3.0 * small <= big <= 5.0 * small, (small, big)  # 4 times the width, about 4 times the text
