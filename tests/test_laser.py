"""Laser-triangulation altimeter (rovslam.vision.laser)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synth import (
    draw_laser_spots,
    laser_hit_pixels,
    paper_camera,
    paper_lasers,
    seabed_frame,
    seabed_spectrum,
)

from rovslam.camera import Camera, LaserPointer
from rovslam.config import LaserConfig
from rovslam.errors import InvalidArgumentError, InvalidMeasurementError
from rovslam.vision.laser import (
    LaserAltimeter,
    fuse_altitude,
    lasers_never_in_view,
    predict_spot_pixels,
    spot_altitude_sigmas,
    triangulate_points,
    triangulate_spots,
)
from rovslam.vision.spots import detect_laser_spots, find_faint_spots, red_excess

CAM = paper_camera()
LASERS = paper_lasers()
CFG = LaserConfig()
SPEC = seabed_spectrum(seed=31)


def _frame(altitude_m: float, seed: int, hide=(), slope=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    rgb = seabed_frame(SPEC, (7.0 * seed, 3.0 * seed), seed=seed)
    uv = laser_hit_pixels(CAM, LASERS, altitude_m, *slope)
    shown = uv.copy()
    shown[list(hide)] = np.nan
    return draw_laser_spots(rgb, shown, seed=seed), uv


@pytest.mark.parametrize("altitude_m", [1.0, 1.31, 2.5])
def test_laser_altitude_within_one_percent_with_default_noise(altitude_m):
    rel = []
    for seed in range(5):
        rgb, uv = _frame(altitude_m, seed)
        est = LaserAltimeter(CAM, LASERS, CFG, fallback_altitude_m=1.31).measure(rgb)
        assert est.source == "laser" and est.n_spots == 4
        assert est.spots_uv_px.shape == (4, 2)
        assert np.allclose(est.spots_uv_px, uv, atol=0.5)
        assert est.slope_rad is not None  # four spots: a plane (its slope is noisy over 10 cm)
        rel.append(est.altitude_m / altitude_m - 1.0)
        # The stated sigma is the centroid noise propagated through each spot (diagonal
        # baseline b sqrt(2)), averaged over the four spots.
        per_spot = altitude_m**2 * CFG.spot_sigma_px / (1075 * 0.05 * np.sqrt(2))
        assert est.sigma_m == pytest.approx(per_spot / 2, rel=0.05)
    assert np.max(np.abs(rel)) < 0.01
    assert np.max(np.abs(rel)) < 0.004  # in fact well inside


def test_one_hidden_spot_still_gives_an_altitude():
    rgb, uv = _frame(1.31, seed=7, hide=(2,))
    est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb)
    assert est.source == "laser" and est.n_spots == 3
    assert est.altitude_m == pytest.approx(1.31, rel=0.01)
    assert len(est.spots_uv_px) == 3


def test_two_spots_and_one_spot_still_give_an_altitude():
    for hide in [(0, 3), (0, 1, 2)]:
        rgb, _ = _frame(2.0, seed=8, hide=hide)
        est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb)
        assert est.source == "laser" and est.n_spots == 4 - len(hide)
        assert est.altitude_m == pytest.approx(2.0, rel=0.01)
        assert est.slope_rad is None


def test_no_spot_falls_back_to_sonar_or_the_fixed_altitude():
    rgb, _ = _frame(1.31, seed=9, hide=(0, 1, 2, 3))
    alt = LaserAltimeter(CAM, LASERS, CFG, fallback_altitude_m=1.5)
    est = alt.measure(rgb)
    assert (est.source, est.altitude_m, est.sigma_m, est.n_spots) == ("fixed", 1.5, CFG.fixed_altitude_sigma_m, 0)
    assert est.spots_uv_px.shape == (0, 2)
    est = alt.measure(rgb, sonar_altitude_m=1.42)
    assert (est.source, est.altitude_m, est.sigma_m) == ("sonar", 1.42, CFG.sonar_sigma_m)
    assert alt.measure(rgb, sonar_altitude_m=float("nan")).source == "fixed"  # empty csv cell


def test_laser_and_sonar_are_variance_weighted():
    rgb, _ = _frame(1.31, seed=10)
    est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb, sonar_altitude_m=1.40)
    laser_only = est.laser_altitude_m  # laser-only value kept for diagnostics
    assert est.source == "laser+sonar"
    w_l = 1.0 / (1.31**2 * CFG.spot_sigma_px / (1075 * 0.05 * np.sqrt(2)) / 2) ** 2
    w_s = 1.0 / CFG.sonar_sigma_m**2
    assert est.altitude_m == pytest.approx((w_l * laser_only + w_s * 1.40) / (w_l + w_s), rel=1e-3)
    assert est.sigma_m < CFG.sonar_sigma_m and est.altitude_m < 1.32


def test_fuse_altitude_rejects_the_spot_that_disagrees():
    alts = np.array([1.30, 1.31, 1.60, 1.32])
    sig = np.full(4, 0.01)
    est = fuse_altitude(alts, sig, None, 1.0, CFG)
    assert est.n_spots == 3 and est.altitude_m == pytest.approx(1.31)
    assert est.sigma_m == pytest.approx(0.01 / np.sqrt(3))
    # Two spots that disagree, no sonar: neither can be trusted.
    assert fuse_altitude(np.array([1.0, 1.5]), np.full(2, 0.01), None, 1.2, CFG).source == "fixed"
    # With a sonar reading, the spot that agrees with it is kept.
    est = fuse_altitude(np.array([1.0, 1.5]), np.full(2, 0.01), 1.48, 1.2, CFG)
    assert est.n_spots == 1 and est.laser_altitude_m == pytest.approx(1.5)


def test_fuse_altitude_input_checks():
    with pytest.raises(InvalidMeasurementError, match="sonar"):
        fuse_altitude(np.array([1.0]), np.array([0.1]), -2.0, 1.31, CFG)
    with pytest.raises(InvalidMeasurementError, match="fallback"):
        fuse_altitude(np.array([1.0]), np.array([0.1]), None, 0.0, CFG)
    with pytest.raises(InvalidArgumentError, match="one sigma per spot"):
        fuse_altitude(np.array([1.0, 2.0]), np.array([0.1]), None, 1.31, CFG)


def test_an_extra_red_blob_is_an_outlier_or_unassociated():
    _, uv = _frame(1.31, seed=11)
    # A red object 12 px from laser 0's spot, stronger than it, and laser 0's own spot hidden.
    rgb, _ = _frame(1.31, seed=11, hide=(0,))
    rgb = draw_laser_spots(rgb, uv[:1] + [12.0, 12.0], seed=1, radius_px=3.5)
    est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb)
    assert est.n_spots == 3 and est.altitude_m == pytest.approx(1.31, rel=0.01)
    assert len(est.spots_uv_px) == 4  # the red blob is still reported for the inhibition mask


def test_sloped_seabed_plane_fit_gives_altitude_below_camera_and_slope():
    slope = (np.tan(np.radians(15.0)), np.tan(np.radians(-10.0)))
    slopes = []
    for seed in range(12, 18):
        rgb, _ = _frame(1.5, seed=seed, slope=slope)
        est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb)
        assert est.n_spots == 4
        assert est.altitude_m == pytest.approx(1.5, rel=0.01)
        slopes.append(np.degrees(est.slope_rad))
    slopes = np.array(slopes)
    # Over the rig's 10 cm baseline one frame's slope is only good to a few degrees.
    assert np.all(np.abs(slopes - [15.0, -10.0]) < 6.0)
    assert np.allclose(slopes.mean(axis=0), [15.0, -10.0], atol=2.0)


def test_tilted_pointers_and_attitude_triangulate_exactly():
    cam = Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5, distortion=(-0.1, 0.02, 0.0, 0.0, 0.0))
    d = np.array([0.0, -0.12, 1.0])
    lasers = (
        LaserPointer((0.1, 0.15, 0.02), tuple(d / np.linalg.norm(d))),
        LaserPointer((-0.1, 0.0, 0.0), (0.05, 0.0, 1.0)),
        LaserPointer((0.0, -0.12, 0.0)),
    )
    for z, roll, pitch in [(1.0, 0.0, 0.0), (2.2, 0.05, -0.03), (0.8, -0.1, 0.08)]:
        uv = predict_spot_pixels(cam, lasers, z, roll, pitch)
        assert np.all(np.isfinite(uv))
        assert np.allclose(triangulate_spots(cam, lasers, uv, roll, pitch), z, rtol=1e-7)
    # A laser through the camera centre has no baseline: no altitude from it.
    centre = (LaserPointer((0.0, 0.0, 0.0)),)
    assert np.isnan(triangulate_spots(CAM, centre, np.array([[179.5, 135.5]]))[0])


def test_predicted_spots_of_the_paper_rig():
    uv = predict_spot_pixels(CAM, LASERS, 1.31)
    off = 1075.0 * 0.05 / 1.31
    # origin (+0.05 fwd, +0.05 stbd) -> above the centre (v smaller) and to the right.
    assert np.allclose(uv[0], [179.5 + off, 135.5 - off])
    assert np.allclose(np.abs(uv - [179.5, 135.5]), off)


def test_spot_sigma_matches_the_parallel_pointer_formula():
    uv = predict_spot_pixels(CAM, LASERS, 2.0)
    sig = spot_altitude_sigmas(CAM, LASERS, uv, 0.3)
    # Z = f b / d per axis with b = 0.05 m on both axes: sqrt(2) baseline along the diagonal.
    assert np.allclose(sig, 2.0**2 * 0.3 / (1075.0 * 0.05 * np.sqrt(2)), rtol=0.02)


def test_detect_laser_spots_association_and_unassociated_mode():
    rgb, uv = _frame(1.31, seed=13, hide=(1,))
    found = detect_laser_spots(rgb, predict_spot_pixels(CAM, LASERS, 1.31), CFG)
    assert found.shape == (4, 2)
    assert np.isnan(found[1]).all()
    assert np.allclose(found[[0, 2, 3]], uv[[0, 2, 3]], atol=0.5)
    blobs = detect_laser_spots(rgb, None, CFG)
    assert blobs.shape == (3, 2)
    # Prediction far from every spot: nothing associated.
    far = detect_laser_spots(rgb, np.array([[10.0, 10.0]]), CFG)
    assert np.isnan(far).all()


@pytest.mark.parametrize("value", [0, 128, 255])
def test_featureless_frames_fall_back_without_raising(value):
    rgb = np.full((272, 360, 3), value, np.uint8)
    est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb)
    assert est.source == "fixed" and est.n_spots == 0


def test_altimeter_follows_the_altitude_and_handles_grey_frames():
    alt = LaserAltimeter(CAM, LASERS, CFG, fallback_altitude_m=1.0)
    for z in [1.0, 1.4, 1.9, 2.5, 3.2]:  # each step within the spot search radius
        rgb, _ = _frame(z, seed=int(z * 10))
        est = alt.measure(rgb)
        assert est.source == "laser" and est.altitude_m == pytest.approx(z, rel=0.01)
    assert alt.last_altitude_m == pytest.approx(3.2, rel=0.01)
    est = alt.measure(np.zeros((272, 360), np.uint8), sonar_altitude_m=3.0)
    assert est.source == "sonar"
    alt.reset()
    assert alt.last_altitude_m == 1.0


def test_laser_input_checks():
    with pytest.raises(InvalidArgumentError, match="uint8 RGB"):
        red_excess(np.zeros((5, 5, 3), np.float32))
    with pytest.raises(InvalidArgumentError, match="one row per laser"):
        triangulate_points(CAM, LASERS, np.zeros((3, 2)))
    with pytest.raises(InvalidMeasurementError, match="altitude_m"):
        predict_spot_pixels(CAM, LASERS, -1.0)
    with pytest.raises(InvalidArgumentError, match="fallback"):
        LaserAltimeter(CAM, LASERS, CFG, float("nan"))
    with pytest.raises(InvalidMeasurementError, match="roll"):
        predict_spot_pixels(CAM, LASERS, 1.0, roll_rad=float("inf"))
    assert dataclasses.is_dataclass(fuse_altitude(np.zeros(0), np.zeros(0), None, 1.0, CFG))


@pytest.mark.parametrize(
    "faint, truth_m, fallback_m, rel", [(False, 0.6, 2.5, 0.01), (True, 1.31, 1.8, 0.005)], ids=["bright", "faint"]
)
def test_spots_far_from_the_prediction_are_found_by_the_altitude_search(faint, truth_m, fallback_m, rel):
    # bright: the spots are ~70 px from where the fallback puts them; faint (no spot seen yet): 11 px outside
    # the faint search around their prediction
    rgb = _faint_frame(truth_m, seed=4)[0] if faint else _frame(truth_m, seed=14)[0]
    alt = LaserAltimeter(CAM, LASERS, CFG, fallback_altitude_m=fallback_m)
    est = alt.measure(rgb)
    assert est.source == "laser" and est.n_spots == 4
    assert est.altitude_m == pytest.approx(truth_m, rel=rel)
    assert alt.last_altitude_m == pytest.approx(truth_m, rel=rel)


def _smeared_spot(centre_uv, pedestal: int = 0, neighbour_uv=None) -> np.ndarray:
    """(60, 60, 3) a Gaussian red spot (sigma 1.2 px, peak 230) smeared by a zero-mean but lopsided
    kernel (the light's centroid stays at ``centre_uv``; 40 % of it lands in a faint tail on one
    side, 1-4 px away, mostly below the 60 threshold), on a grey seabed with a red pedestal."""
    h = w = 60
    vv, uu = np.indices((h, w), dtype=np.float64)
    # kernel taps along u: 0.6 at -1.5 px, 0.4 spread over +1..+4 px, shifted to a first moment of 0
    taps = [(-1.5, 0.6)] + [(d, 0.4 / 4) for d in (1.0, 2.0, 3.0, 4.0)]
    shift = -sum(d * a for d, a in taps)  # put the first moment back at exactly 0
    smeared = (
        sum(
            a * np.exp(-((uu - centre_uv[0] - d - shift) ** 2 + (vv - centre_uv[1]) ** 2) / (2 * 1.2**2))
            for d, a in taps
        )
        * 230.0
    )
    red = 60.0 + pedestal + smeared
    if neighbour_uv is not None:  # another red blob nearby (a second pointer, a red sponge)
        red += 200.0 * (((uu - neighbour_uv[0]) ** 2 + (vv - neighbour_uv[1]) ** 2) <= 4.0)
    img = np.full((h, w, 3), 60, np.uint8)
    img[..., 0] = np.clip(np.rint(red), 0, 255).astype(np.uint8)
    return img


def _light_centroid(img: np.ndarray, pedestal: int = 0) -> np.ndarray:
    ex = np.maximum(red_excess(img).astype(np.float64) - pedestal, 0.0)
    vv, uu = np.indices(ex.shape)
    return np.array([(ex * uu).sum() / ex.sum(), (ex * vv).sum() / ex.sum()])


@pytest.mark.parametrize("centre", [(30.0, 30.0), (29.3, 31.6), (30.5, 30.25)])
def test_a_lopsided_smear_does_not_move_the_spot_centre(centre):
    img = _smeared_spot(centre)
    truth = _light_centroid(img)  # (the rounding to 8 bits moves it by a few thousandths)
    assert np.allclose(truth, centre, atol=0.02)
    got = detect_laser_spots(img, np.array([centre]), CFG)[0]
    assert np.all(np.abs(got - truth) < 0.05), (got, truth)
    # control: the thresholded pixels alone (the detector before) lose the faint tail
    old = detect_laser_spots(img, np.array([centre]), dataclasses.replace(CFG, spot_skirt_px=0.0))[0]
    assert old[0] - truth[0] < -0.3, (old, truth)


def test_the_spot_centre_ignores_a_red_pedestal_and_a_neighbouring_blob():
    centre = (30.0, 30.0)
    img = _smeared_spot(centre, pedestal=25, neighbour_uv=(30.0, 38.0))
    truth = _light_centroid(_smeared_spot(centre), pedestal=0)
    got = detect_laser_spots(img, np.array([centre]), CFG)[0]
    assert np.all(np.abs(got - truth) < 0.05), (got, truth)


def _faint_frame(altitude_m: float, seed: int, peak: float = 42.0, extra_uv=()) -> tuple[np.ndarray, np.ndarray]:
    """A seabed frame with faint laser spots: Gaussian (sigma 0.9 px) red light whose dominance peaks near
    ``peak``, a quarter of it bleeding into green (the simulator's coral preset), never 3 px above 60."""
    rgb = seabed_frame(SPEC, (5.0 * seed, 2.0 * seed), seed=seed).astype(np.float64)
    uv = laser_hit_pixels(CAM, LASERS, altitude_m)
    vv, uu = np.indices(rgb.shape[:2], dtype=np.float64)
    light = np.zeros(rgb.shape[:2])
    for cu, cv in list(uv) + list(extra_uv):
        light += np.exp(-((uu - cu) ** 2 + (vv - cv) ** 2) / (2 * 0.9**2))
    excess_before = rgb[..., 0] - np.maximum(rgb[..., 1], rgb[..., 2])
    assert excess_before.max() < 0  # the seabed itself has no red dominance
    base = np.maximum(rgb[..., 1], rgb[..., 2]) - rgb[..., 0]  # lift red to the others' level, then the light
    rgb[..., 0] += np.where(light > 0.02, base, 0.0) + peak / 0.75 * light
    rgb[..., 1] += 0.25 * peak / 0.75 * light
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8), uv


def test_faint_spots_near_their_prediction_are_found():
    rgb, uv = _faint_frame(1.31, seed=3)
    assert np.all(np.isnan(detect_laser_spots(rgb, uv, CFG)))  # below min_red_excess: the bright pass sees none
    found = find_faint_spots(rgb, uv + [[0.8, -1.1]], detect_laser_spots(rgb, uv, CFG), CFG)
    assert np.all(np.abs(found - uv) < 0.15), found - uv
    est = LaserAltimeter(CAM, LASERS, CFG, 1.31).measure(rgb)
    assert est.source == "laser" and est.n_spots == 4
    assert est.altitude_m == pytest.approx(1.31, rel=0.005)
    off = dataclasses.replace(CFG, faint_red_excess=0.0)
    assert LaserAltimeter(CAM, LASERS, off, 1.31).measure(rgb).source == "fixed"  # control: as before


def test_a_faint_peak_with_red_beside_it_is_no_spot():
    uv = laser_hit_pixels(CAM, LASERS, 1.31)
    # a second faint blob 5 px from laser 0's (a red sponge, a reflection): which one is the spot?
    rgb, _ = _faint_frame(1.31, seed=5, extra_uv=[uv[0] + [5.0, 0.0]])
    found = find_faint_spots(rgb, uv, np.full((4, 2), np.nan), CFG)
    assert np.all(np.isnan(found[0]))
    assert np.all(np.abs(found[1:] - uv[1:]) < 0.15)
    # a peak below faint_red_excess is noise, not a spot
    dim, _ = _faint_frame(1.31, seed=5, peak=12.0)
    assert np.all(np.isnan(find_faint_spots(dim, uv, np.full((4, 2), np.nan), CFG)))


def test_lasers_never_in_view_names_a_pointer_mounted_in_the_wrong_units():
    assert lasers_never_in_view(CAM, LASERS, CFG.min_altitude_m, CFG.max_altitude_m) == []
    far = (LaserPointer((5.0, 0.05, 0.0)),) + LASERS[1:]  # 5 m forward: millimetres for metres
    assert lasers_never_in_view(CAM, far, CFG.min_altitude_m, CFG.max_altitude_m) == [0]
    # a beam tilted 30 degrees forward is outside the 360x272 image (a half-angle of 9.6 degrees) at any altitude
    assert lasers_never_in_view(CAM, (LaserPointer((0.05, 0.05, 0.0), (0.5, 0.0, 0.866)),), 0.05, 30.0) == [0]
    # one converging on the axis (1.6 degrees) enters the image from 0.34 m: in view
    converging = (LaserPointer((0.05, 0.05, 0.0), (-0.02, -0.02, 1.0)),)
    assert lasers_never_in_view(CAM, converging, 0.05, 30.0) == []
    assert lasers_never_in_view(CAM, converging, 0.05, 0.3) == [0]
