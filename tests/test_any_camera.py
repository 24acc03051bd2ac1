"""Issue 12, "Any camera, any motion": the processing scale, large motions, an honest start.

* Resolution: any camera is processed near the paper's pixels (``[processing]``), and every
  pixel the results report is in the camera's own frame, consistent with its intrinsics.
* Large motions: the first pair, a pair after a gap, a still camera at 1.5 Hz with 50 %
  overlap and a pair moving a third of the image give a speed; the tokens are chosen where
  the seabed stays in view; a weak phase-correlation prior the tokens confirm is accepted.
* The real Sparus video decimated to every 2nd, 3rd and 4th frame gives the full-rate path.
* Start-up: the first steps' Q carries the relief the tokens have not measured yet.
* HD: upscaled simulator frames (fast) and the ``hd-survey`` preset (slow) against the
  360x272-class run of the same dive.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import cv2
import datasets
import numpy as np
import pytest
from synth import colourise, paper_camera, render_grey, seabed_spectrum

from rovslam.camera import Camera, ground_to_pixels, pixels_to_ground
from rovslam.config import (
    ConfigError,
    OdometryConfig,
    ProcessingConfig,
    RunConfig,
    SpeedTemplateConfig,
    TrackerConfig,
    from_dict,
)
from rovslam.core import Frame, SequenceInfo
from rovslam.io.sequence import open_sequence
from rovslam.pipeline import SlamPipeline
from rovslam.sensor.odometry import SpeedEstimator
from rovslam.vision.filters import bandpass, local_variance, template_channel, template_channel_u8
from rovslam.vision.scale import ProcessingScale, auto_scale, processing_scale
from rovslam.vision.tracking import TokenTracker, leaving_mask

ROOT = Path(__file__).resolve().parents[1]
SPARUS = datasets.folder("sparus")
needs_sparus = datasets.needs("sparus")
Z_M = 1.3
HD = Camera(width_px=1920, height_px=1080, fx_px=4800.0, fy_px=4800.0, cx_px=959.5, cy_px=539.5)


# --------------------------------------------------------------------------- the processing scale


def test_processing_config_is_auto_by_default_and_validated_at_load():
    assert ProcessingConfig().scale == "auto"
    assert from_dict(RunConfig, {"processing": {"scale": 1}}).processing.scale == 1.0
    assert from_dict(RunConfig, {"processing": {"scale": "auto", "max_side_px": 640}}).processing.max_side_px == 640
    for bad, says in [
        ({"scale": 0.0}, "(0, 1]"),
        ({"scale": 1.5}, "(0, 1]"),
        ({"scale": "half"}, "'auto'"),
        ({"scale": True}, "number"),
        ({"max_side_px": 10}, ">= 64"),
    ]:
        with pytest.raises(ConfigError, match=re.escape(says)) as exc:
            from_dict(RunConfig, {"processing": bad}, "run.toml")
        assert "run.toml" in str(exc.value) and "[processing]" in str(exc.value)


def test_auto_scale_keeps_the_papers_camera_and_reduces_hd_to_the_papers_pixels():
    assert auto_scale(paper_camera(), 1.31) == 1.0
    sparus = Camera(384, 288, 405.6, 405.6, 189.9, 139.9)
    assert auto_scale(sparus, 1.8) == 1.0
    assert auto_scale(HD, Z_M) == pytest.approx(0.25)
    # The same 1920x1080 sensor behind a wide lens (a 2.5 m wide footprint): 480 px would leave
    # 190 px/m; the ground-resolution floor (500 px/m) keeps more.
    wide = dataclasses.replace(HD, fx_px=1000.0, fy_px=1000.0)
    s = auto_scale(wide, Z_M)
    assert s == pytest.approx(500.0 * Z_M / 1000.0) and s * 1000.0 / Z_M == pytest.approx(500.0)
    assert processing_scale(HD, ProcessingConfig(scale=0.5), Z_M).camera.width_px == 960


@pytest.mark.parametrize(
    "size_wh, scale",
    [((1920, 1080), 0.25), ((1920, 1080), 0.5), ((1440, 810), 1 / 3), ((1200, 900), 0.2), ((1280, 720), 0.3)],
)
def test_a_channel_is_reduced_as_its_float_copy_bit_for_bit(size_wh, scale):
    """The whole-factor block sums (and the general path) give OpenCV's area average of the float32 channel exactly."""
    w, h = size_wh
    sc = ProcessingScale.for_camera(Camera(w, h, 1000.0, 1000.0, (w - 1) / 2, (h - 1) / 2), scale)
    rng = np.random.default_rng(w + h)
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    rgb[: h // 3] = 255  # saturated rows: the largest sums
    for channel in ("green", "blue", "grey"):
        ch = template_channel_u8(rgb, channel)
        want = sc.reduce(template_channel(rgb, channel))
        got = sc.reduce_channel(ch)
        assert got.dtype == np.float32 and got.shape == want.shape == (sc.camera.height_px, sc.camera.width_px)
        assert np.array_equal(got, want), (channel, np.abs(got - want).max())


def test_processed_pixels_map_to_the_full_frame_through_the_camera_model():
    """A seabed point projects to the same full-resolution pixel through either camera (distortion included)."""
    cam = dataclasses.replace(HD, distortion=(-0.30, 0.12, 0.001, -0.0005, 0.0), cx_px=951.3, cy_px=544.8)
    sc = ProcessingScale.for_camera(cam, 0.25)
    assert (sc.camera.width_px, sc.camera.height_px) == (480, 270)
    rng = np.random.default_rng(1)
    ground = rng.uniform([-0.12, -0.22], [0.12, 0.22], (50, 2))
    full_uv = ground_to_pixels(cam, ground, Z_M)
    proc_uv = ground_to_pixels(sc.camera, ground, Z_M)
    np.testing.assert_allclose(sc.to_full_px(proc_uv), full_uv, atol=1e-6)
    np.testing.assert_allclose(sc.to_processed_px(full_uv), proc_uv, atol=1e-6)
    np.testing.assert_allclose(pixels_to_ground(sc.camera, proc_uv, Z_M), ground, atol=1e-9)
    # The area reduction puts a bright pixel block where the mapping says.
    img = np.zeros((1080, 1920), np.uint8)
    img[400:404, 1000:1004] = 255  # full-resolution centre (1001.5, 401.5)
    small = sc.reduce(img).astype(float)
    v, u = np.unravel_index(np.argmax(small), small.shape)
    np.testing.assert_allclose([u, v], sc.to_processed_px(np.array([1001.5, 401.5])), atol=1e-9)


def test_laser_figures_follow_the_scale():
    sc = ProcessingScale.for_camera(HD, 0.25)
    cfg = RunConfig().laser
    las = sc.laser_config(cfg)
    assert las.search_radius_px == pytest.approx(4 * cfg.search_radius_px)
    assert las.max_spot_area_px == 16 * cfg.max_spot_area_px and las.min_spot_area_px == cfg.min_spot_area_px
    assert las.spot_sigma_px == pytest.approx(4 * cfg.spot_sigma_px)
    assert las.faint_search_radius_px == pytest.approx(4 * cfg.faint_search_radius_px)
    assert ProcessingScale.for_camera(paper_camera(), 1.0).laser_config(cfg) is cfg


# --------------------------------------------------------------------------- large motions


def _track_image(rgb: np.ndarray) -> np.ndarray:
    return bandpass(template_channel(rgb, "green"), 1.0, 4.0)


@pytest.fixture(scope="module")
def spectrum():
    return seabed_spectrum((512, 1024), seed=1)


def test_tokens_are_chosen_where_the_seabed_stays_in_view(spectrum):
    """A third of the image of motion: the tokens are chosen again away from the band that leaves."""
    a = _track_image(colourise(render_grey(spectrum, (0.0, 0.0)), seed=1))
    b = _track_image(colourise(render_grey(spectrum, (0.0, -90.0)), seed=2))  # content moves 90 px down
    tracker = TokenTracker(SpeedTemplateConfig(), TrackerConfig())
    tracker.extract(a, local_variance(a, 16))
    shift, conf = tracker.motion_prior(b)
    np.testing.assert_allclose(shift, [0.0, 90.0], atol=0.5)
    leaving_before = sum(t.centre_uv_px[1] + 90.0 > 272 - 9 for t in tracker.tokens)
    assert leaving_before >= 2  # chosen without knowing the motion, some were bound to leave
    assert tracker.reselect_for_motion(shift)
    assert all(t.centre_uv_px[1] + 90.0 + 7.5 < 272 - 4 for t in tracker.tokens)
    tracks = tracker.track(b, None)
    assert tracks.n_tracked == len(tracker.tokens) == 8
    np.testing.assert_allclose(np.median(tracks.displacements_uv_px, axis=0), [0.0, 90.0], atol=0.1)
    # The band: u + du or v + dv within the margin of the border or beyond.
    m = leaving_mask((272, 360), np.array([-20.0, 90.0]), 5.0)
    assert m[:, :25].all() and not m[:176, 25:].any() and m[177:, :].all()


def test_a_weak_global_prior_is_accepted_when_the_tokens_confirm_it(spectrum):
    """Whatever the phase correlation's raw confidence: tokens found around it, moving together, confirm it."""
    a = _track_image(colourise(render_grey(spectrum, (0.0, 0.0)), seed=1))
    b = _track_image(colourise(render_grey(spectrum, (-40.0, -60.0)), seed=2))
    strict = dataclasses.replace(TrackerConfig(), min_global_confidence=0.99)  # every prior is "weak"
    tracker = TokenTracker(SpeedTemplateConfig(), strict)
    tracker.extract(a, local_variance(a, 16))
    tracker.reselect_for_motion(tracker.motion_prior(b)[0])  # as the pipeline does: tokens that stay in view
    tracks = tracker.track(b, None)
    assert tracks.global_confidence < 0.99 and tracks.used_global_search
    assert tracks.n_tracked == 8
    np.testing.assert_allclose(np.median(tracks.displacements_uv_px, axis=0), [40.0, 60.0], atol=0.1)
    # An unrelated image: the weak prior is not confirmed, nothing is tracked.
    other = _track_image(colourise(render_grey(seabed_spectrum((512, 1024), seed=9), (0.0, 0.0)), seed=3))
    tracker.extract(a, local_variance(a, 16))
    assert tracker.track(other, None).n_tracked <= 1


def _run_frames(camera: Camera, frames: list[np.ndarray], times_s: list[float], config: RunConfig = RunConfig()):
    info = SequenceInfo(name="large motions", camera=camera, lasers=(), fixed_altitude_m=Z_M)
    pipe = SlamPipeline(info, config)
    return [pipe.process(Frame(k, t, img, 0.0)) for k, (img, t) in enumerate(zip(frames, times_s))]


def _check_speeds(results, offsets_px, times_s, camera: Camera, rel_tol: float) -> None:
    """Every pair gives a speed, within ``rel_tol`` of the truth (content offset o: the vehicle moves -o Z / f)."""
    for k in range(1, len(results)):
        dt = times_s[k] - times_s[k - 1]
        du, dv = np.subtract(offsets_px[k], offsets_px[k - 1])
        truth = np.array([-dv * Z_M / camera.fy_px, du * Z_M / camera.fx_px]) / dt  # surge (image up), sway (right)
        r = results[k]
        assert r.speed_ok, f"pair {k}: no speed ({r.tokens_tracked} tokens)"
        got = np.array([r.surge_mps, r.sway_mps])
        assert np.linalg.norm(got - truth) <= rel_tol * np.linalg.norm(truth), (k, got, truth)


def test_first_pair_a_third_of_the_image_and_a_gap_give_a_speed(spectrum):
    """The first pair moves 90 of 272 rows; then 20 px steps at 5 Hz; then a 1 s gap (100 px)."""
    cam = paper_camera()
    offsets = [(0.0, 0.0), (0.0, 90.0), (4.0, 110.0), (8.0, 130.0), (28.0, 230.0)]
    times = [0.0, 0.2, 0.4, 0.6, 1.6]
    frames = [colourise(render_grey(spectrum, o), seed=k) for k, o in enumerate(offsets)]
    res = _run_frames(cam, frames, times)
    _check_speeds(res, offsets, times, cam, 0.01)
    assert min(r.tokens_tracked for r in res[1:]) >= 6


def test_a_still_camera_at_half_overlap_gives_a_speed_every_pair():
    """1024x768 at 1.5 Hz, 50 % overlap (384 rows of motion per frame), processed at 480x360."""
    cam = Camera(1024, 768, 1400.0, 1400.0, 511.5, 383.5)
    spec = seabed_spectrum((1024, 2048), seed=2, sigmas_px=(2.0, 4.0, 8.0, 16.0))
    offsets = [(10.0 * k, -384.0 * k + 3 * 384.0) for k in range(4)]
    times = [k / 1.5 for k in range(4)]
    frames = [colourise(render_grey(spec, o, (768, 1024)), seed=k) for k, o in enumerate(offsets)]
    res = _run_frames(cam, frames, times)
    _check_speeds(res, offsets, times, cam, 0.01)
    assert min(r.tokens_tracked for r in res[1:]) >= 6
    assert res[1].token_uv_px.max(axis=0)[1] > 400  # reported in the 1024x768 frame, not the processed one


# --------------------------------------------------------------------------- the real Sparus video, decimated


@needs_sparus
def test_sparus_decimated_gives_the_full_rate_path():
    """Every 2nd, 3rd, 4th frame (real motions of 14 to 28 px): the path within 10 % of its length."""
    from rovslam.io.source import InputOptions
    from rovslam.runner import open_source

    src = open_source(
        SPARUS / "sparus_snippet.mp4",
        options=InputOptions(
            camera_file=ROOT / "examples" / "sparus-camera.toml", nav_file=SPARUS / "sparus_snippet.csv"
        ),
    )
    frames = list(src.frames())

    def path(step: int) -> tuple[np.ndarray, list]:
        pipe = SlamPipeline(src.info, RunConfig())
        res = [pipe.process(f) for f in frames[::step]]
        return np.array([[r.x_m, r.y_m] for r in res]), res

    full, _ = path(1)
    length_m = float(np.sum(np.linalg.norm(np.diff(full, axis=0), axis=1)))
    assert length_m > 0.5
    for step in (2, 3, 4):
        xy, res = path(step)
        err = np.linalg.norm(xy - full[::step], axis=1)
        assert err.max() <= 0.10 * length_m, (step, err.max() / length_m)
        assert sum(r.speed_ok for r in res[1:]) >= len(res) - 2  # at most one pair without a speed


# --------------------------------------------------------------------------- start-up


def test_the_first_steps_q_carries_the_relief_not_yet_measured():
    """Before any frame has measured the relief, Q holds the prior's scale error; it fades as data come in."""
    cam = paper_camera()
    rng = np.random.default_rng(4)
    uv0 = rng.uniform([40, 40], [320, 232], (8, 2))
    uv1 = uv0 + [0.0, -20.0]  # a flat seabed: every token moves the same
    est = SpeedEstimator(OdometryConfig())
    flat = SpeedEstimator(OdometryConfig(relief_prior_sigma=0.0))
    first = est.measure(cam, uv0, uv1, Z_M, Z_M, 0.2)
    first_flat = flat.measure(cam, uv0, uv1, Z_M, Z_M, 0.2)
    speed = np.hypot(first.surge_mps, first.sway_mps)
    assert first.ok and first_flat.ok
    # The prior (2 % of the altitude) as the relief term of Q: gain^2 sigma^2 (1/n + 1/m) |v|^2 along the motion.
    relief_var = 0.02**2  # the prior alone: no frame has measured the relief yet
    expected = 2.0**2 * relief_var * (1.0 / 8 + 1.0) * speed**2
    assert first.cov_mps2[0, 0] - first_flat.cov_mps2[0, 0] == pytest.approx(expected, rel=1e-6)
    assert np.sqrt(first.cov_mps2[0, 0]) > 2.0 * np.sqrt(first_flat.cov_mps2[0, 0])
    for _ in range(9):  # with the first, 2 s (relief_prior_s) of a flat seabed: the prior's share is down to 1/e
        est.measure(cam, uv0, uv1, Z_M, Z_M, 0.2)
    assert est.relief_var == pytest.approx(math.exp(-1.0) * relief_var, rel=1e-6)
    for _ in range(140):  # 30 s: the measured relief has taken over
        last = est.measure(cam, uv0, uv1, Z_M, Z_M, 0.2)
    assert est.relief_var < 1e-6 * relief_var
    assert last.cov_mps2[0, 0] == pytest.approx(first_flat.cov_mps2[0, 0], rel=0.05)


# --------------------------------------------------------------------------- HD against the paper's pixels


def _ate_m(results, gt_xy: np.ndarray) -> float:
    xy = np.array([[r.x_m, r.y_m] for r in results])
    return float(np.sqrt(np.mean(np.sum((xy - gt_xy[: len(xy)]) ** 2, axis=1))))


def _groundtruth_xy(seq: Path) -> np.ndarray:
    g = np.genfromtxt(seq / "groundtruth.csv", delimiter=",", names=True)
    return np.column_stack([g["x_m"], g["y_m"]])


def _upscaled(info: SequenceInfo, factor: int) -> SequenceInfo:
    cam = info.camera
    big = dataclasses.replace(
        cam,
        width_px=cam.width_px * factor,
        height_px=cam.height_px * factor,
        fx_px=cam.fx_px * factor,
        fy_px=cam.fy_px * factor,
        cx_px=(cam.cx_px + 0.5) * factor - 0.5,
        cy_px=(cam.cy_px + 0.5) * factor - 0.5,
    )
    return dataclasses.replace(info, camera=big)


def test_upscaled_frames_run_as_well_as_the_papers_and_report_full_resolution_pixels(tmp_path):
    """The paper's camera and the same frames at 4x (1440x1088, processed at 480x363): ATE within 1.5x."""
    from rovslam.sim import simulate

    simulate("portofino-short", tmp_path / "seq", frames=150, seed=2)
    seq = open_sequence(tmp_path / "seq")
    frames = list(seq.frames())
    gt = _groundtruth_xy(tmp_path / "seq")
    small = SlamPipeline(seq.info, RunConfig())
    ref = [small.process(f) for f in frames]
    big_info = _upscaled(seq.info, 4)
    big = SlamPipeline(big_info, RunConfig())
    assert (big.camera.width_px, big.camera.height_px) == (480, 363)
    hd = [
        big.process(dataclasses.replace(f, image=cv2.resize(f.image, (1440, 1088), interpolation=cv2.INTER_CUBIC)))
        for f in frames
    ]
    ate_ref, ate_hd = _ate_m(ref, gt), _ate_m(hd, gt)
    assert ate_hd <= 1.5 * max(ate_ref, 0.5e-3), (ate_hd, ate_ref)
    assert sum(r.speed_ok for r in hd) >= sum(r.speed_ok for r in ref) - 2
    # Pixels in the 1440x1088 frame: the laser spots where the 360x272 run saw them, times 4.
    for a, b in zip(ref[::30], hd[::30]):
        assert len(a.laser_spots_uv_px) == len(b.laser_spots_uv_px) == 4
        np.testing.assert_allclose(b.laser_spots_uv_px, (a.laser_spots_uv_px + 0.5) * 4 - 0.5, atol=1.5)
        assert b.measurements.focal_px == pytest.approx(big_info.camera.focal_px)
    obs = [o for r in hd for o in r.observations]
    assert obs and all(0 <= o.uv_px[0] < 1440 and 0 <= o.uv_px[1] < 1088 for o in obs)
    # [m, n] in full-resolution pixels: the offset of uv from the principal point (a level camera, no distortion).
    cam = big_info.camera
    for o in obs[:10]:
        np.testing.assert_allclose(o.mn_px, [cam.cy_px - o.uv_px[1], o.uv_px[0] - cam.cx_px], atol=0.05)
    toks = np.concatenate([r.token_uv_px for r in hd[1:]])
    assert toks[:, 0].max() > 1000 and toks[:, 1].max() > 800


@pytest.mark.slow
def test_hd_survey_runs_as_well_as_the_same_dive_at_the_papers_resolution(tmp_path, monkeypatch):
    """``hd-survey`` (1920x1080 at 25 Hz, processed at 480x270) against the same dive seen by a 360x272 camera."""
    from rovslam.sim import scenarios, simulate

    hd = scenarios.SCENARIOS["hd-survey"]
    f = hd.camera.fx_px * 360 / 1920  # the same 52 cm wide footprint
    low = dataclasses.replace(
        hd,
        name="hd-survey-360",
        camera=Camera(360, 272, f, f, 179.5, 135.5),
        sensor=dataclasses.replace(hd.sensor, psf_sigma_px=hd.sensor.psf_sigma_px * 360 / 1920),
    )
    monkeypatch.setitem(scenarios.SCENARIOS, "hd-survey-360", low)
    n = 500
    out = {}
    for name in ("hd-survey", "hd-survey-360"):
        simulate(name, tmp_path / name, frames=n, seed=1)
        seq = open_sequence(tmp_path / name)
        pipe = SlamPipeline(seq.info, RunConfig())
        out[name] = _ate_m([pipe.process(fr) for fr in seq.frames()], _groundtruth_xy(tmp_path / name))
    assert out["hd-survey"] <= 1.5 * out["hd-survey-360"], out
