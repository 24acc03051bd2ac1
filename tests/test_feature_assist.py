"""Step 5 with weak tokens: the feature motion seeds, gates and stands in for them (rovslam.pipeline.assist).

On pairs cut from the real chamber3 photomosaic (tests/chamber_pairs.py: 30 to 70 % overlap, turns of
5 to 20 degrees, 2 to 5 % zoom, each also at a quarter of the contrast) the loop's speed gives the
displacement within 10 %, or with a covariance holding the truth. Measured before the feature
motion was used (tokens only, ``feature_assist_inliers = 0``): 4 of the 12 pairs passed, the 8 with
a turn or a zoom gave no speed (the held zero); with it all 12 pass, within 1.1 % (2.3 px).

On the real Sparus video decimated by 4 and by 8, the path between the first and the last frame
kept is within 10 % of the full-rate path's length and direction. Measured: by 4, 0.988 of the length
and 0.5 degrees apart (tokens only: 0.976, 2.2 degrees); by 8, 0.948 and 0.9 degrees (tokens only: no
speed in either step, no path).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import chamber_pairs as cp
import datasets
import numpy as np
import pytest

from rovslam.config import OdometryConfig, RunConfig
from rovslam.errors import ConfigError
from rovslam.eval.feature_reference import FeatureReference, PairComparison
from rovslam.pipeline.assist import beyond_reach, feature_speed, is_weak, predicted_tokens, token_gate
from rovslam.sensor.odometry import SpeedMeasurement
from rovslam.vision.features import FeatureMotion

ROOT = Path(__file__).resolve().parents[1]
TOKENS_ONLY = dataclasses.replace(RunConfig(), odometry=dataclasses.replace(OdometryConfig(), feature_assist_inliers=0))


@pytest.fixture(scope="module")
def mosaic():
    datasets.skip_unless("chamber3")
    return cp.load_mosaic(datasets.folder("chamber3") / "seabed.jpg")


@pytest.mark.parametrize("spec", cp.PAIRS, ids=[p.name for p in cp.PAIRS])
def test_photomosaic_pair_gives_its_displacement(mosaic, spec):
    r = cp.measure_pair(mosaic, spec)
    assert r.speed_ok, cp.table([r])
    assert r.relative <= 0.10 or r.sigmas <= math.sqrt(9.21), cp.table([r])
    assert r.sigmas <= 3.03, cp.table([r])  # and its covariance holds the truth (all pairs do, measured <= 1.0)


def test_tokens_alone_fail_the_turned_and_zoomed_pairs(mosaic):
    """What the feature motion is for: without it, the pairs with a turn or a zoom give no speed."""
    results = [cp.measure_pair(mosaic, p, TOKENS_ONLY) for p in cp.PAIRS]
    failing = {r.spec.name for r in results if not r.passes}
    assert failing == {p.name for p in cp.PAIRS if p.turn_deg != 0.0}, cp.table(results)


def test_seeded_tokens_measure_some_turned_pairs_themselves(mosaic):
    """Searched around the feature motion's prediction, the tokens are found again on the 10 and 5 degree pairs
    (measured: 4 of 8 agree) and give the speed themselves; the feature motion is the speed only where they fail."""
    results = [cp.measure_pair(mosaic, p) for p in cp.BASE_PAIRS if p.turn_deg in (10.0, 5.0)]
    assert [r.inliers >= 3 for r in results] == [True, True], cp.table(results)


def test_flat_pairs_unchanged_when_tokens_are_strong(mosaic):
    """Pure translation: the tokens agree (8 of 8), the feature motion is never asked; bit for bit the same speed."""
    for spec in (cp.PAIRS[0], cp.PAIRS[1]):
        a, b = cp.measure_pair(mosaic, spec), cp.measure_pair(mosaic, spec, TOKENS_ONLY)
        assert a.inliers >= 7
        assert np.array_equal(a.measured_px, b.measured_px) and np.array_equal(a.cov_px2, b.cov_px2)


def _motion(params, cov=None) -> FeatureMotion:
    c = np.diag([1e-8, 1e-8, 0.04, 0.04]) if cov is None else cov
    return FeatureMotion(True, "", np.asarray(params, dtype=np.float64), c, 100, 80, 0.8, 0.3)


def test_gate_refuses_tokens_off_the_feature_motion():
    cam = cp.CAMERA
    motion = _motion([1.0, 0.0, 40.0, -25.0])
    uv0 = np.array([[100.0, 100.0], [200.0, 150.0], [50.0, 220.0], [300.0, 60.0]])
    uv1 = uv0 + [40.0, -25.0]
    uv1[1] += [3.0, 0.0]  # 3 px off: a wrong match
    uv1[2] = np.nan  # lost
    keep = token_gate(cam, motion, uv0, uv1, token_sigma_px=0.5, sigmas=3.0)
    assert keep.tolist() == [True, False, False, True]
    pred, cov = predicted_tokens(cam, motion, uv0)
    assert np.allclose(pred, uv0 + [40.0, -25.0]) and cov.shape == (4, 2, 2)


def test_feature_speed_with_a_covariance_from_the_motion():
    """A 100 px move down the image at Z = 1.31 m, f = 1075 px, in 0.2 s: 0.609 m/s forward, its sigma from the motion's."""
    cam = cp.CAMERA
    step = dict(altitude_prev_m=1.31, altitude_curr_m=1.31, dt_s=0.2, dpsi_rad=0.0, dpsi_sigma_rad=0.01)
    step["config"] = dataclasses.replace(OdometryConfig(), min_inliers=1, outlier_threshold_px=50.0, token_scale=True)
    a = feature_speed(cam, _motion([1.0, 0.0, 0.0, 100.0]), 5, step)
    b = feature_speed(cam, _motion([1.0, 0.0, 0.0, 100.0], np.diag([1e-8, 1e-8, 4.0, 4.0])), 5, step)
    assert a.ok and a.source == "features" and a.n_inliers == 0 and a.inlier_mask.shape == (5,)
    assert a.surge_mps == pytest.approx(100 * 1.31 / 1075 / 0.2, rel=1e-3) and abs(a.sway_mps) < 1e-6
    px_per_mps = 1075 / 1.31 * 0.2
    # sigma 2 px on the translation -> 2 px of speed (plus the floors): the covariance follows the motion's
    assert math.sqrt(b.cov_mps2[0, 0]) * px_per_mps == pytest.approx(2.0, rel=0.15)
    assert b.cov_mps2[0, 0] > 10 * a.cov_mps2[0, 0]


def test_weak_is_few_inliers_or_none():
    def m(ok, n):
        return SpeedMeasurement(ok, 0.0, 0.0, np.eye(2), 8, n, np.zeros(8, bool), "")

    assert is_weak(m(True, 2), 3) and is_weak(m(False, 0), 3)
    assert not is_weak(m(True, 3), 3) and not is_weak(m(False, 0), 0)


def test_trigger_threshold_is_checked():
    with pytest.raises(ConfigError):
        OdometryConfig(feature_assist_inliers=-1)
    with pytest.raises(ConfigError):
        OdometryConfig(feature_gate_sigmas=0.0)


# --------------------------------------------------------------------------- the real Sparus video, decimated


def _sparus_paths(config: RunConfig) -> dict[int, np.ndarray]:
    """{every k: (2,) x, y displacement between frame 0 and the last frame kept}, and the full rate's over the same span."""
    from rovslam.io.source import InputOptions
    from rovslam.pipeline import SlamPipeline
    from rovslam.runner import open_source

    folder = datasets.folder("sparus")
    opts = InputOptions(camera_file=ROOT / "examples" / "sparus-camera.toml", nav_file=folder / "sparus_snippet.csv")
    src = open_source(folder / "sparus_snippet.mp4", options=opts)
    frames = list(src.frames())
    out: dict[int, np.ndarray] = {}
    full: dict[int, np.ndarray] = {}
    for k in (1, 4, 8):
        pipe = SlamPipeline(src.info, config)
        res = {f.index: np.array([r.x_m, r.y_m]) for f in frames[::k] for r in [pipe.process(f)]}
        if k == 1:
            full = res
        last = max(res)
        out[k] = res[last] - res[0]
        out[-k] = full[last] - full[0]
    return out


@datasets.needs("sparus")
def test_decimated_sparus_path_matches_the_full_rate():
    d = _sparus_paths(cp.ASSISTED)
    for k in (4, 8):
        dec, full = d[k], d[-k]
        ratio = float(np.linalg.norm(dec) / np.linalg.norm(full))
        angle = math.degrees(abs(math.remainder(math.atan2(dec[1], dec[0]) - math.atan2(full[1], full[0]), math.tau)))
        # within 10 % of the length, and of the direction (10 % of a radian: 5.7 degrees)
        assert abs(ratio - 1.0) <= 0.10 and angle <= 5.7, (k, ratio, angle)


# --------------------------------------------------------------------------- the report's figure


def _reference_block() -> dict:
    rng = np.random.default_rng(4)
    pairs = []
    for k in range(1, 40):
        tok = np.array([0.0, 6.0]) + rng.normal(0.0, 0.1, 2)
        feat = tok + rng.normal(0.0, 0.1, 2) + (np.array([0.0, 9.0]) if k in (17, 30) else 0.0)
        rel = float(np.linalg.norm(feat - tok) / np.linalg.norm(tok))
        pairs.append(PairComparison(k - 1, k, 0.2 * k, tok, feat, rel, 10.0 * rel, held=k == 30))
    return FeatureReference(pairs).to_dict()


def test_report_plots_the_feature_reference(tmp_path):
    from rovslam.runner import run_sequence
    from rovslam.sim import simulate
    from rovslam.viz.feature_plot import feature_reference_pairs
    from rovslam.viz.report import write_report

    block = _reference_block()
    cols = feature_reference_pairs(block)
    assert len(cols["t_s"]) == 39 and set(cols["frame"][cols["agrees"] == 0]) == {17.0, 30.0}
    simulate("portofino-short", tmp_path / "seq", frames=12, seed=0)
    run_sequence(tmp_path / "seq", tmp_path / "out")
    html_without = write_report(tmp_path / "out", mosaic=False).read_text()
    assert "Feature reference" not in html_without
    (tmp_path / "out" / "eval.json").write_text(json.dumps({"feature_reference": block}))
    html = write_report(tmp_path / "out", mosaic=False).read_text()
    png = tmp_path / "out" / "report" / "feature_reference.png"
    assert png.is_file() and png.stat().st_size > 10_000
    assert "Feature reference" in html and "39 of 39 frame pairs compared, 94.9 % agree" in html
    assert html.count("<img") == html_without.count("<img") + 1


def test_feature_plot_from_worst_pairs_only(tmp_path):
    """An eval.json written before every pair was listed: the worst pairs alone are drawn."""
    from rovslam.viz.feature_plot import plot_feature_reference

    block = _reference_block()
    del block["per_pair"]
    assert plot_feature_reference(block, tmp_path / "f.png") == tmp_path / "f.png"
    assert plot_feature_reference({"worst": [], "pairs": 3}, tmp_path / "g.png") is None


def test_a_turn_the_compass_did_not_see_is_refused():
    """A frame that is not the next view of the seabed (a glitch) must not become a motion: 35 degrees against 0."""
    from rovslam.pipeline.assist import turn_agrees

    c, s = math.cos(math.radians(35.0)), math.sin(math.radians(35.0))
    turned = _motion([c, s, 10.0, 0.0])  # the image turns +35 degrees: the vehicle turned -35
    sigma = math.sqrt(2.0) * math.radians(0.5)
    assert not turn_agrees(turned, (0.0,), sigma, 3.0)
    assert turn_agrees(turned, (0.0, math.radians(-35.0)), sigma, 3.0)  # the reading saw it
    assert turn_agrees(turned, (0.0,), None, 3.0)  # no compass: nothing to check against


def test_speed_source_says_where_the_features_stood_in(mosaic):
    """``speed_source``: "tokens" on a pure translation, "features" where the tokens failed under a turn and a zoom."""
    flat = cp.measure_pair(mosaic, cp.PAIRS[0])
    assert flat.source == "tokens" and flat.inliers >= 7
    results = [cp.measure_pair(mosaic, p) for p in cp.PAIRS if p.turn_deg != 0.0]
    sources = {r.source for r in results}
    assert sources == {"tokens", "features"}, cp.table(results)  # re-seeded tokens on some, the features on others
    assert all(r.inliers == 0 for r in results if r.source == "features"), cp.table(results)


def test_beyond_reach_only_when_the_motion_leaves_the_search_windows():
    """A 30 px motion: beyond an 8 px window around zero, within one around the phase correlation's 28 px."""
    cam = cp.CAMERA
    uv = np.array([[100.0, 80.0], [200.0, 150.0], [250.0, 60.0], [150.0, 200.0]])
    shift = _motion([1.0, 0.0, 30.0, 0.0])
    zero = np.zeros((4, 2))
    assert beyond_reach(cam, shift, uv, [(zero, 8.0)])
    assert not beyond_reach(cam, shift, uv, [(zero, 8.0), (zero + [28.0, 0.0], 12.0)])
    assert not beyond_reach(cam, _motion([1.0, 0.0, 3.0, -2.0]), uv, [(zero, 8.0)])  # a small motion: within reach
    # a 15 degree turn about the image centre moves the corner tokens 30 px and more: beyond a window at the mean
    c, s = math.cos(math.radians(15.0)), math.sin(math.radians(15.0))
    cx, cy = cam.cx_px, cam.cy_px
    turned = _motion([c, s, cx - c * cx + s * cy, cy - s * cx - c * cy])
    corners = np.array([[20.0, 20.0], [340.0, 20.0], [20.0, 250.0], [340.0, 250.0]])
    assert beyond_reach(cam, turned, corners, [(zero, 12.0)])
    assert not beyond_reach(cam, shift, np.zeros((0, 2)), [(np.zeros((0, 2)), 8.0)])  # no tokens: nothing to seed
