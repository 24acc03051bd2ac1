"""Rolling shutter: row times, token and landmark corrections, and the speed bias they remove."""

import dataclasses
import shutil

import numpy as np
import pytest
from synth import simulate_variant

from rovslam.camera import Camera, rot2
from rovslam.errors import SequenceFormatError
from rovslam.io.sequence import open_sequence
from rovslam.runner import run_sequence
from rovslam.sensor.shutter import mn_at_frame_time, mn_rate_px_s, tokens_at_frame_time
from rovslam.sim.render import SensorParams
from rovslam.sim.vehicle import VehicleParams

CAM = Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5, readout_s=0.03)


def test_row_time_spans_the_readout_about_the_middle_row():
    t = CAM.row_time_s(np.array([0.0, 135.5, 271.0]))
    np.testing.assert_allclose(t, [-0.015, 0.0, 0.015], atol=1e-15)
    assert np.all(dataclasses.replace(CAM, readout_s=0.0).row_time_s(np.array([0.0, 271.0])) == 0.0)


@pytest.mark.parametrize("readout_s", [-0.001, float("nan"), float("inf"), 30.0])
def test_impossible_readout_is_a_named_error(readout_s):
    with pytest.raises(SequenceFormatError, match="readout_s"):
        dataclasses.replace(CAM, readout_s=readout_s)


def _observed(p0: np.ndarray, w_px_s: np.ndarray, t_frame_s: float, cam: Camera) -> np.ndarray:
    """Where points at ``p0`` (frame time 0), moving at ``w_px_s``, are seen in the frame of time ``t_frame_s``.

    Row v is exposed at ``t_frame + row_time(v)`` while the point moves: solved exactly for v.
    """
    k = cam.readout_s / (cam.height_px - 1)
    c = 0.5 * (cam.height_px - 1)
    v = (p0[:, 1] + w_px_s[1] * (t_frame_s - k * c)) / (1.0 - w_px_s[1] * k)
    t = t_frame_s + cam.row_time_s(v)
    return np.column_stack([p0[:, 0] + w_px_s[0] * t, v])


def test_tokens_moved_to_the_frame_time_are_exact_for_a_steady_image_motion():
    rng = np.random.default_rng(7)
    p0 = rng.uniform([20, 20], [340, 250], size=(8, 2))
    w = np.array([-12.0, 150.0])  # px/s: moving forward, the seabed slides down the image
    dt = 0.2
    a, b = _observed(p0, w, 0.0, CAM), _observed(p0, w, dt, CAM)
    raw = b - a
    assert np.max(np.abs(raw[:, 1] - w[1] * dt)) > 0.1  # uncorrected: the rows' delays change the shift
    a2, b2 = tokens_at_frame_time(CAM, a, b, dt)
    np.testing.assert_allclose(a2, p0, atol=1e-9)
    np.testing.assert_allclose(b2 - a2, np.broadcast_to(w * dt, p0.shape), atol=1e-9)


def test_global_shutter_leaves_the_tokens_as_they_are():
    a = np.array([[10.0, 20.0]])
    b = np.array([[11.0, 25.0]])
    cam = dataclasses.replace(CAM, readout_s=0.0)
    out = tokens_at_frame_time(cam, a, b, 0.2)
    assert out[0] is a and out[1] is b


def test_landmark_seen_late_in_the_readout_is_moved_back_to_the_frame_pose():
    # A landmark of the world seen from a vehicle moving at 0.15 m/s surge, 0.05 sway, turning at
    # 0.2 rad/s. With a rolling shutter its row is exposed at row_time(v): iterate to that instant.
    f, Z = CAM.focal_px, 1.31
    speed = np.array([0.15, 0.05])
    omega, psi0, x0 = 0.2, 0.4, np.array([1.0, 2.0])
    X = x0 + rot2(psi0) @ np.array([0.09, -0.05])  # forward of the camera: low rows, seen early

    def mn_at(t):
        psi = psi0 + omega * t
        x = x0 + rot2(psi0) @ speed * t  # (first order in t is enough here)
        return (f / Z) * rot2(psi).T @ (X - x)

    t = 0.0
    for _ in range(50):
        mn = mn_at(t)
        t = float(CAM.row_time_s(CAM.cy_px - mn[0]))
    v = CAM.cy_px - mn[0]
    assert abs(t) > 0.004
    raw_error = np.linalg.norm(mn - mn_at(0.0))
    rate = mn_rate_px_s(mn, speed, omega, Z, f)
    fixed = mn_at_frame_time(CAM, v, mn, rate)
    assert raw_error > 0.5  # pixels: what the filter would take for a vehicle or map error
    assert np.linalg.norm(fixed - mn_at(0.0)) < 0.01 * raw_error


@pytest.fixture(scope="module")
def rolling_shutter_dive(tmp_path_factory):
    """80 frames at 0.3 m/s under a 30 ms rolling shutter (flat seabed, the paper's camera)."""
    return simulate_variant(
        tmp_path_factory.mktemp("rs") / "seq",
        "portofino-short",
        "test-rolling-shutter",
        seed=3,
        n_frames=80,
        sensor=dataclasses.replace(SensorParams(), readout_s=0.03),
        vehicle=dataclasses.replace(VehicleParams(), cruise_speed_mps=0.3, accel_limit_mps2=0.3),
    )


def _surge_error_mps(seq, out) -> tuple[np.ndarray, np.ndarray]:
    """(surge error, true surge) over the frames faster than 0.15 m/s, forward or back."""
    tr = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True)
    gt = np.genfromtxt(seq / "groundtruth.csv", delimiter=",", names=True)
    dt = np.diff(gt["t_s"])
    vx, vy, psi = np.diff(gt["x_m"]) / dt, np.diff(gt["y_m"]) / dt, gt["heading_rad"][:-1]
    u = np.cos(psi) * vx + np.sin(psi) * vy
    fast = (np.abs(u) > 0.15) & (tr["speed_ok"][1:] > 0)
    assert fast.sum() >= 40
    return tr["surge_mps"][1:][fast] - u[fast], u[fast]


def test_sequence_records_the_readout_and_the_speed_bias_is_gone(rolling_shutter_dive, tmp_path):
    seq = rolling_shutter_dive
    assert open_sequence(seq).info.camera.readout_s == pytest.approx(0.03)
    run_sequence(seq, tmp_path / "known")
    err_known, u = _surge_error_mps(seq, tmp_path / "known")
    # The same frames with the readout left out of sequence.toml: the surge reads f readout u^2 / (Z H)
    # too high, forward and back alike.
    toml = (seq / "sequence.toml").read_text()
    blind = tmp_path / "blind"
    shutil.copytree(seq, blind)
    (blind / "sequence.toml").write_text(toml.replace("readout_s = 0.03\n", ""))
    run_sequence(blind, tmp_path / "blind_out")
    err_blind, _ = _surge_error_mps(blind, tmp_path / "blind_out")
    expected_bias = 1075.0 * 0.03 / (1.31 * 271.0) * np.mean(u**2)  # 8 mm/s at 0.3 m/s
    assert np.mean(err_blind) == pytest.approx(expected_bias, rel=0.35)
    assert abs(np.mean(err_known)) < 0.15 * expected_bias
