"""The smoothing back end (GTSAM iSAM2) on synthetic measurement streams, without images.

As the EKF's Monte Carlo tests: a grid survey with revisits, seeded noise, the EKF fed the
same records as the pipeline feeds it. Figures are printed (``pytest -s``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import chi2
from synth import SurveyNoise, crosshatch_track, landmark_field, lawnmower_track, survey_measurements
from typer.testing import CliRunner

from rovslam.camera import rot2
from rovslam.cli import app
from rovslam.config import SlamConfig
from rovslam.errors import ConfigError, FilterInconsistencyError, InvalidMeasurementError
from rovslam.io.measurements import write_measurements
from rovslam.slam import EkfSlam, MotionInput, observation_noise_px2, observe_mn
from rovslam.slam.apparent import apparent_frame_cov_m2
from rovslam.slam.measurements import FrameMeasurements, LandmarkMeasurement
from rovslam.slam.smoother import Isam2Smoother, SmootherConfig

# The paper's grid (0.7 m square, lanes 17.5 cm apart, flown north-south then east-west), 100 s:
# the start area is passed over again and again. The compass has its white noise (0.5 deg)
# and a slow drift of 0.1 deg (the drift the smoother cannot see from the map: see
# test_monte_carlo_with_a_strongly_drifting_compass).
GRID_FRAMES = 500
NOISE = SurveyNoise(drift_sigma_rad=np.deg2rad(0.1))


def smoother_config(noise: SurveyNoise = NOISE, **changes) -> SmootherConfig:
    return SmootherConfig(heading_bias_sigma_rad=noise.drift_sigma_rad, heading_bias_tau_s=noise.drift_tau_s, **changes)


def run_ekf(frames, noise: SurveyNoise = NOISE):
    """The EKF fed the records as the pipeline feeds it: (K, 2) positions, (K, 2, 2) covariances."""
    ekf = EkfSlam(
        SlamConfig(
            landmark_height_sigma_m=0.0,
            altitude_bias_sigma_m=0.0,
            speed_bias_sigma_mps=0.0,
            heading_bias_sigma_rad=noise.drift_sigma_rad,
            heading_bias_tau_s=noise.drift_tau_s,
            pixel_sigma_px=noise.pixel_sigma_px,
        )
    )
    xy, cov = np.zeros((len(frames), 2)), np.zeros((len(frames), 2, 2))
    prev = None
    for k, f in enumerate(frames):
        if prev is not None:
            ekf.predict(
                MotionInput(
                    f.speed_mps[0], f.speed_mps[1], f.speed_cov_mps2, prev.heading_rad, f.dt_s, f.heading_sigma_rad
                )
            )
        for ob in f.landmarks:
            if ob.kind == "init":
                assert (
                    ekf.augment(
                        ob.mn_px, f.heading_rad, f.altitude_m, f.focal_px, heading_sigma_rad=f.heading_sigma_rad
                    )
                    == ob.landmark_id
                )
            else:
                ekf.update(
                    ob.landmark_id,
                    ob.mn_px,
                    f.heading_rad,
                    f.altitude_m,
                    f.focal_px,
                    heading_sigma_rad=f.heading_sigma_rad,
                )
        xy[k], cov[k] = ekf.vehicle_xy_m, ekf.vehicle_cov_m2
        prev = f
    return xy, cov


def smooth(frames, config: SmootherConfig):
    sm = Isam2Smoother(config)
    online = [sm.add_frame(f) for f in frames]
    return sm, online, sm.smoothed()


def ate_m(xy, truth) -> float:
    return float(np.sqrt(np.mean(np.sum((xy - truth) ** 2, axis=1))))


def mahalanobis(xy, cov, truth) -> np.ndarray:
    e = xy - truth
    return np.sqrt(np.einsum("ki,kij,kj->k", e, np.linalg.inv(cov), e))


def grid_survey(seed, noise=NOISE, frames=GRID_FRAMES):
    xy, psi = crosshatch_track(frames)
    return survey_measurements(seed, xy, psi, landmark_field(seed, xy), noise)


def monte_carlo(runs, noise=NOISE, frames=GRID_FRAMES):
    wins, ratios, nees = 0, [], []
    for s in range(runs):
        sv = grid_survey(1000 + s, noise, frames)
        # relief_rounds=0: the flat seabed of the EKF it is compared with (heights: the relief tests below)
        _, _, res = smooth(sv.frames, smoother_config(noise, relief_rounds=0))
        ekf_xy, _ = run_ekf(sv.frames, noise)
        a_s, a_e = ate_m(res.xy_m, sv.xy_m), ate_m(ekf_xy, sv.xy_m)
        wins += a_s < a_e
        ratios.append(a_s / a_e)
        nees.append(mahalanobis(res.xy_m[1:], res.cov_xy_m2[1:], sv.xy_m[1:]) ** 2)  # frame 0: the known start
    mean = np.mean(nees, axis=0)
    lo, hi = chi2.ppf([0.025, 0.975], 2 * runs) / runs
    inside = float(np.mean((mean >= lo) & (mean <= hi)))
    return wins / runs, float(np.median(ratios)), inside, float(mean.mean())


# ---------------------------------------------------------------- acceptance
def test_monte_carlo_smoothed_path_beats_the_online_ekf_and_is_consistent():
    win_rate, ratio, inside, mean_nees = monte_carlo(50)
    print(
        f"\ngrid survey, 50 runs: smoothed ATE < EKF online ATE in {win_rate:.0%} of runs "
        f"(median ratio {ratio:.2f}); smoothed NEES inside the 95 % interval on {inside:.1%} of steps "
        f"(mean {mean_nees:.2f})"
    )
    assert win_rate >= 0.90
    assert ratio < 0.8
    assert inside >= 0.90
    assert 1.6 < mean_nees < 2.4


@pytest.mark.slow
def test_monte_carlo_with_a_strongly_drifting_compass():
    # The run's default compass drift (0.5 deg, 120 s): the drift turns the whole map about
    # the start, which no revisit can see; smoothing still helps, less often.
    noise = SurveyNoise()
    win_rate, ratio, inside, mean_nees = monte_carlo(50, noise, frames=900)
    print(
        f"\ndrifting compass (0.5 deg), 50 runs: smoothed better in {win_rate:.0%} (median ratio {ratio:.2f}); "
        f"NEES inside on {inside:.1%} of steps (mean {mean_nees:.2f})"
    )
    assert win_rate >= 0.6 and ratio < 1.0
    assert inside >= 0.90


def inject_wrong_association(frames, truth_landmarks, k_min=250):
    """Frame index and a copy of ``frames`` where one observation is attributed to a wrong landmark.

    At the first frame from ``k_min`` on that tracks a landmark A, a second observation is
    added: A's pixels under the id of the landmark B farthest from A (the template matched
    somewhere else): its residual is tens of centimetres.
    """
    for k in range(k_min, len(frames)):
        tracks = [ob for ob in frames[k].landmarks if ob.kind == "track"]
        if len(tracks) == 1:
            a = tracks[0]
            d = np.hypot(*(truth_landmarks - truth_landmarks[a.landmark_id]).T)
            b = int(np.argmax(d))
            wrong = LandmarkMeasurement(b, "track", a.mn_px, a.noise_px2, accepted_by_online=False)
            out = list(frames)
            out[k] = dataclasses.replace(frames[k], landmarks=frames[k].landmarks + (wrong,))
            return k, out, float(d[b])
    raise AssertionError("no frame tracks a single landmark")


def test_one_wrong_association_is_down_weighted_by_the_robust_loss():
    # The same survey smoothed with and without one wrong association: under a robust loss
    # the wrong one moves no pose by more than 2 sigma and the truth stays as well covered;
    # least squares bends the whole path by hundreds of sigma.
    for seed in (11, 12, 13, 14):
        sv = grid_survey(seed)
        k, frames, dist_m = inject_wrong_association(sv.frames, sv.landmarks_xy_m)
        _, _, clean = smooth(sv.frames, smoother_config())
        cover_clean = np.mean(mahalanobis(clean.xy_m[1:], clean.cov_xy_m2[1:], sv.xy_m[1:]) <= 2.0)
        report = []
        for loss in ("huber", "cauchy", "none"):
            _, _, res = smooth(frames, smoother_config(robust=loss))
            shift = mahalanobis(res.xy_m[1:], clean.cov_xy_m2[1:], clean.xy_m[1:]).max()
            cover = np.mean(mahalanobis(res.xy_m[1:], res.cov_xy_m2[1:], sv.xy_m[1:]) <= 2.0)
            report.append(f"{loss}: moved by {shift:.2f} sigma, truth inside 2 sigma on {cover:.0%}")
            if loss == "none":
                assert shift > 20.0 and cover < 0.2
            else:
                assert shift < 2.0 and cover >= cover_clean - 0.05
                assert res.landmark_downweighted.sum() >= 1  # the wrong one is flagged
        print(
            f"\nseed {seed}: wrong association at frame {k}, {100 * dist_m:.0f} cm off (clean: truth inside "
            f"2 sigma on {cover_clean:.0%}); " + "; ".join(report)
        )


# ---------------------------------------------------------------- the model, piece by piece
def test_online_estimate_of_the_last_pose_is_the_smoothed_one():
    # Least squares: the last pose given every frame is the same number both ways (up to the
    # linearisation points). Under the robust loss the online pass keeps the weights it gave a
    # revisit when it arrived (a large residual then), so its covariance is a little larger.
    # relief_rounds=0: the online pass has no heights; with them the final smoothing is another model.
    sv = grid_survey(5, frames=300)
    _, online_ls, res_ls = smooth(sv.frames, smoother_config(robust="none", relief_rounds=0))
    sigma = math.sqrt(np.trace(res_ls.cov_xy_m2[-1]) / 2)
    assert np.linalg.norm(online_ls[-1].xy_m - res_ls.xy_m[-1]) < 0.05 * sigma
    np.testing.assert_allclose(online_ls[-1].cov_xy_m2, res_ls.cov_xy_m2[-1], rtol=0.01, atol=1e-3 * sigma**2)
    sm, online, res = smooth(sv.frames, smoother_config(relief_rounds=0))
    assert [o.index for o in online] == list(range(300)) and res.index.tolist() == list(range(300))
    last = online[-1]
    assert np.linalg.norm(last.xy_m - res.xy_m[-1]) < 0.2 * sigma
    assert np.all(np.linalg.eigvalsh(last.cov_xy_m2 - res.cov_xy_m2[-1]) > -1e-3 * sigma**2)
    np.testing.assert_allclose(last.cov_xy_m2, res.cov_xy_m2[-1], rtol=0.2, atol=1e-3 * sigma**2)
    # The online estimate is causal: the past it returned is worse than the smoothed past.
    online_xy = np.array([o.xy_m for o in online])
    assert ate_m(res.xy_m, sv.xy_m) < ate_m(online_xy, sv.xy_m)
    assert res.landmark_ids.tolist() == list(range(len(sv.landmarks_xy_m)))
    lm_err = mahalanobis(res.landmarks_xy_m, res.landmarks_cov_m2, sv.landmarks_xy_m)
    assert np.mean(lm_err <= 2.0) > 0.8
    assert np.all(res.landmark_observations >= 1) and res.landmark_observations.sum() == sum(
        len(f.landmarks) for f in sv.frames
    )
    # The online landmark (read from its marginal) is iSAM2's solution (a full back-substitution),
    # close to the smoothed one.
    best = sm._isam.calculateBestEstimate()
    for i in (0, len(res.landmark_ids) - 1):
        np.testing.assert_allclose(sm.landmark_xy_m(i), best.atPoint2(sm._l(i)), atol=1e-12)
        np.testing.assert_allclose(sm.landmark_cov_m2(i), sm._isam.marginalCovariance(sm._l(i)), rtol=1e-9)
        np.testing.assert_allclose(
            sm.landmark_xy_m(i), res.landmarks_xy_m[i], atol=3 * math.sqrt(res.landmarks_cov_m2[i, 0, 0])
        )


def straight_frames(n, compass_sigma=0.01, step_sigma=0.002, frame_changes=None):
    """n frames at 0.1 m/s, heading 0.3 rad, no landmark; ``frame_changes``: {frame index: field changes}."""
    frame_changes = frame_changes or {}
    frames = []
    for k in range(n):
        f = FrameMeasurements(
            index=k,
            t_s=0.2 * k,
            dt_s=0.2 if k else 0.0,
            speed_mps=[0.1, 0.0],
            speed_cov_mps2=np.eye(2) * 1e-6 if k else np.zeros((2, 2)),
            speed_ok=k > 0,
            heading_rad=0.3,
            heading_sigma_rad=compass_sigma,
            compass_rad=0.3,
            compass_sigma_rad=compass_sigma,
            heading_step_rad=0.0 if k else np.nan,
            heading_step_sigma_rad=step_sigma if k else np.nan,
            altitude_m=1.31,
            altitude_sigma_m=0.0,
            focal_px=1075.0,
        )
        frames.append(dataclasses.replace(f, **frame_changes.get(k, {})))
    return frames


def test_the_heading_part_equals_a_dense_gaussian_with_the_ornstein_uhlenbeck_drift():
    # Without landmarks the positions absorb nothing of the headings: the headings and the
    # drift blocks form a linear-Gaussian problem on their own. Its dense solution, with the
    # drift's prior written as the OU covariance s^2 a^|i-j| of the block values, must equal
    # the graph's marginals (the prior is split into links and priors, swapped as blocks open).
    s, tau, block, s_c, s_step = 0.01, 20.0, 2.0, 0.005, 0.002
    n, n_blocks = 51, 6  # 10 s
    rng = np.random.default_rng(4)
    compass = 0.3 + rng.normal(0.0, 0.01, n)
    frames = [dataclasses.replace(f, compass_rad=float(c)) for f, c in zip(straight_frames(n, s_c, s_step), compass)]
    sm = Isam2Smoother(SmootherConfig(heading_bias_sigma_rad=s, heading_bias_tau_s=tau, bias_block_s=block))
    for f in frames:
        sm.add_frame(f)
    res = sm.smoothed()

    a = math.exp(-block / tau)
    within = 2 * s * s * (1 - math.exp(-block / (4 * tau)))
    j_of = np.minimum(np.floor(np.arange(n) * 0.2 / block + 1e-9).astype(int), n_blocks - 1)
    rows, rhs, w = [], [], []
    for k in range(n):  # compass: psi_k + b_j = c_k
        r = np.zeros(n + n_blocks)
        r[k], r[n + j_of[k]] = 1.0, 1.0
        rows.append(r), rhs.append(compass[k]), w.append(1 / (s_c**2 + within))
    for k in range(1, n):  # tokens: psi_k - psi_{k-1} = 0
        r = np.zeros(n + n_blocks)
        r[k], r[k - 1] = 1.0, -1.0
        rows.append(r), rhs.append(0.0), w.append(1 / s_step**2)
    a_mat, w = np.array(rows), np.array(w)
    info = a_mat.T @ (w[:, None] * a_mat)
    ou = s * s * a ** np.abs(np.subtract.outer(np.arange(n_blocks), np.arange(n_blocks)))
    info[n:, n:] += np.linalg.inv(ou)
    info[0, 0] += 1e-8  # the free heading prior of the first pose
    cov = np.linalg.inv(info)
    mean = cov @ (a_mat.T @ (w * np.array(rhs)))

    import gtsam

    keys = gtsam.KeyVector([gtsam.symbol("m", j) for j in range(n_blocks)])
    joint = sm._isam.jointMarginalCovariance(keys).fullMatrix()[2::3, 2::3]  # the block rotations (-b)
    np.testing.assert_allclose(joint, cov[n:, n:], rtol=1e-5)
    np.testing.assert_allclose(res.heading_rad, mean[:n], atol=1e-7)
    assert sm.heading_bias_rad() == pytest.approx(mean[-1], abs=1e-7)


def test_a_compass_offset_nothing_else_sees_stays_in_the_heading():
    # The compass reads 0.31 while the tokens say the heading never changes. Nothing else
    # knows the absolute heading: the drift keeps its prior mean (0) and the heading takes
    # the compass mean; every step moves R(psi) [u, v] dt by (1).
    frames = [dataclasses.replace(f, compass_rad=0.31) for f in straight_frames(200, compass_sigma=0.005)]
    sm = Isam2Smoother(SmootherConfig(heading_bias_sigma_rad=0.02, heading_bias_tau_s=1e4, bias_block_s=100.0))
    for f in frames:
        sm.add_frame(f)
    res = sm.smoothed()
    assert sm.heading_bias_rad() == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(res.heading_rad, 0.31, atol=1e-9)
    steps = np.diff(res.xy_m, axis=0)
    np.testing.assert_allclose(steps, np.tile(rot2(0.31) @ [0.02, 0.0], (199, 1)), atol=1e-9)
    # Position variance grows along the path from the known start (odometry and heading noise).
    var = res.cov_xy_m2[:, 0, 0] + res.cov_xy_m2[:, 1, 1]
    assert var[0] < 1e-10 and np.all(np.diff(var) > 0)


def test_no_compass_and_no_measured_turn_still_solve():
    # A bare video: no compass at all, some steps without a token turn (loose), a frame
    # skipped by the pipeline in the middle, a landmark seen at the start and at the end.
    changes = {k: dict(compass_rad=np.nan) for k in range(80)}
    for k in (10, 11, 40):
        changes[k].update(heading_step_rad=np.nan, heading_step_sigma_rad=np.nan)
    frames = straight_frames(80, frame_changes=changes)
    truth = np.array([[0.02 * k * math.cos(0.3), 0.02 * k * math.sin(0.3)] for k in range(80)])
    landmark = truth[0] + [0.05, 0.02]
    for k in (0, 79):
        mn = observe_mn(landmark, truth[k], 0.3, 1.31, 1075.0)[0]
        ob = LandmarkMeasurement(0, "init" if k == 0 else "track", mn, observation_noise_px2(mn, 0.5, 1.31))
        frames[k] = dataclasses.replace(frames[k], landmarks=(ob,))
    frames = [f for f in frames if f.index != 50]  # the pipeline skipped frame 50: dt 0.4 s next
    frames[50] = dataclasses.replace(frames[50], dt_s=0.4, speed_mps=[0.1, 0.0])
    sm, online, res = smooth(frames, SmootherConfig())
    assert np.all(np.isfinite(res.xy_m)) and np.all(np.isfinite(res.cov_xy_m2))
    np.testing.assert_allclose(res.heading_rad, 0.3, atol=1e-3)  # the first heading defines the map frame
    np.testing.assert_allclose(res.xy_m[-1], truth[-1], atol=1e-4)
    assert sm.heading_bias_rad() == 0.0  # no compass: no drift block


def test_compass_gaps_open_the_skipped_drift_blocks():
    changes = {k: dict(compass_rad=np.nan) for k in range(20, 70)}  # 10 s without compass
    sm, _, res = smooth(straight_frames(100, frame_changes=changes), SmootherConfig(bias_block_s=1.0))
    assert sm._block == 19  # blocks 0..19 over 19.8 s, those of the gap included
    np.testing.assert_allclose(res.heading_rad, 0.3, atol=2e-3)


@pytest.mark.parametrize(
    "changes,needle",
    [
        (dict(robust="tukey"), "robust"),
        (dict(robust_k=0.0), "robust_k"),
        (dict(relinearize_skip=0), "relinearize_skip"),
        (dict(heading_bias_sigma_rad=-1.0), "heading_bias_sigma_rad"),
        (dict(bias_block_s=math.inf), "bias_block_s"),
        (dict(use_rejected="yes"), "use_rejected"),
        (dict(final_max_iterations=1.5), "final_max_iterations"),
    ],
)
def test_bad_configuration_is_a_config_error(changes, needle):
    with pytest.raises(ConfigError, match=needle) as err:
        SmootherConfig(**changes)
    assert "[smoother]" in str(err.value)


def test_bad_frame_sequences_are_rejected_and_leave_the_graph_unchanged():
    frames = straight_frames(5)
    ob = LandmarkMeasurement(0, "init", [1.0, 2.0], np.eye(2))
    frames[1] = dataclasses.replace(frames[1], landmarks=(ob,))
    sm = Isam2Smoother()
    for f in frames[:3]:
        sm.add_frame(f)
    with pytest.raises(InvalidMeasurementError, match="increasing order"):
        sm.add_frame(frames[1])
    with pytest.raises(InvalidMeasurementError, match="dt_s must be > 0"):
        sm.add_frame(dataclasses.replace(frames[3], dt_s=0.0))
    with pytest.raises(InvalidMeasurementError, match="initialised twice"):
        sm.add_frame(dataclasses.replace(frames[3], landmarks=(ob,)))
    with pytest.raises(InvalidMeasurementError, match="FrameMeasurements"):
        sm.add_frame({"index": 3})
    assert sm.n_poses == 3 and sm.n_landmarks == 1
    sm.add_frame(frames[3])
    assert sm.smoothed().xy_m.shape == (4, 2)
    with pytest.raises(InvalidMeasurementError, match="no frame"):
        Isam2Smoother().smoothed()
    with pytest.raises(InvalidMeasurementError, match="no landmark 7"):
        sm.landmark_cov_m2(7)


def test_an_ill_posed_graph_is_a_typed_one_line_error():
    # A compass of 100 rad noise says nothing and nothing else knows the absolute heading.
    sm = Isam2Smoother(SmootherConfig(bias_block_s=2.0))
    with pytest.raises(FilterInconsistencyError, match="SMOOTHER FAILED in the iSAM2 update of frame") as err:
        for f in straight_frames(51, compass_sigma=100.0):
            sm.add_frame(f)
    assert "\n" not in str(err.value)


def test_rejected_observations_can_be_left_out():
    sv = grid_survey(21, frames=200)
    frames = [
        dataclasses.replace(
            f, landmarks=tuple(dataclasses.replace(ob, accepted_by_online=ob.kind == "init") for ob in f.landmarks)
        )
        for f in sv.frames
    ]
    _, _, res = smooth(frames, smoother_config(use_rejected=False))
    assert np.all(res.landmark_observations == 1)  # the initialisations only


# ---------------------------------------------------------------- rovslam smooth
def test_smooth_command_writes_the_smoothed_files(tmp_path):
    xy, psi = lawnmower_track(n_legs=2)
    sv = survey_measurements(8, xy, psi, landmark_field(8, xy), NOISE)
    write_measurements(tmp_path, sv.frames)
    res = CliRunner().invoke(app, ["smooth", str(tmp_path), "--quiet"])
    assert res.exit_code == 0, res.output
    assert f"{len(sv.frames)} frames" in res.output
    traj = np.genfromtxt(tmp_path / "trajectory_smoothed.csv", delimiter=",", names=True)
    assert traj.dtype.names == ("t_s", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2", "heading_rad")
    _, _, direct = smooth(sv.frames, SmootherConfig())  # no config.toml: the default drift model
    np.testing.assert_allclose(np.column_stack([traj["x_m"], traj["y_m"]]), direct.xy_m, atol=1e-8)
    # The graph's marginals plus what the whole dive shares: the compass's error at the start
    # (0.5 degree by default) turns the estimate about the origin, the altimeter's lasting error
    # (1 cm and the laser rig's 0.76 % of the depth, in quadrature) scales it (no AHRS: no tilt term).
    turned = direct.cov_xy_m2 + apparent_frame_cov_m2(
        direct.xy_m, direct.altitude_m, 0.0, 0.0087, np.hypot(0.01 / direct.altitude_m, 0.0076)
    )
    np.testing.assert_allclose(traj["var_x_m2"], turned[:, 0, 0], rtol=1e-4)
    np.testing.assert_allclose(traj["cov_xy_m2"], turned[:, 0, 1], rtol=1e-4, atol=1e-12)
    far = np.argmax(np.hypot(*direct.xy_m.T))
    assert traj["var_y_m2"][far] > 1.1 * direct.cov_xy_m2[far, 1, 1]  # they matter away from the start
    tum = np.loadtxt(tmp_path / "trajectory_smoothed.tum")
    assert tum.shape == (len(sv.frames), 8)
    np.testing.assert_allclose(tum[:, 3], 1.31)
    np.testing.assert_allclose(2 * np.arctan2(tum[:, 6], tum[:, 7]), direct.heading_rad, atol=1e-7)
    lms = np.genfromtxt(tmp_path / "landmarks_smoothed.csv", delimiter=",", names=True)
    assert lms.dtype.names[:8] == ("id", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2", "first_t_s", "observations")
    assert len(lms) == len(sv.landmarks_xy_m)
    # No wrong association: only the Gaussian tail beyond 3 sigma (1.1 % for 2 dof) is down-weighted.
    assert lms["downweighted"].sum() <= 0.03 * lms["observations"].sum()
    res = CliRunner().invoke(app, ["smooth", str(tmp_path), "--robust", "cauchy", "--robust-k", "2.5", "--quiet"])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(
    "args,needle",
    [
        (["smooth", "EMPTY"], "not the --out folder of a `rovslam run`"),  # audit D9 g: not "an old version"
        (["smooth", "/no/such/run"], "not a folder"),
        (["smooth", "EMPTY", "--robust", "tukey"], "[smoother] robust"),
    ],
)
def test_smooth_command_mistakes_are_one_line_and_exit_2(tmp_path, args, needle):
    args = [a.replace("EMPTY", str(tmp_path)) for a in args]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("rovslam: error:") and needle in lines[0]


# ---------------------------------------------------------------- relief
def relief_survey(seed, sigma_h_m=0.03, frames=GRID_FRAMES):
    """The grid survey over landmarks on relief: heights N(0, sigma_h_m), the seabed under the spots flat."""
    xy, psi = crosshatch_track(frames)
    field = landmark_field(seed, xy)
    heights = np.random.default_rng(seed + 7).normal(0.0, sigma_h_m, len(field))
    sv = survey_measurements(seed, xy, psi, field, NOISE, heights_m=heights)
    return sv, heights[sv.order]


def test_the_landmark_heights_from_every_view_take_the_relief_out_of_the_smoothed_path():
    """Landmarks 3 cm (1 sigma) off the plane the altitude measures: with the flat model of (3), each is
    seen 2 % nearer or farther than it is, so its position moves with where it is in the image; the relief
    rounds estimate every height from all its views and the path follows the truth again."""
    flat_ates, relief_ates, height_errs, truth_rms = [], [], [], []
    for s in range(6):
        sv, heights = relief_survey(2000 + s)
        _, _, flat = smooth(sv.frames, smoother_config(relief_rounds=0))
        _, _, res = smooth(sv.frames, smoother_config())
        flat_ates.append(ate_m(flat.xy_m, sv.xy_m))
        relief_ates.append(ate_m(res.xy_m, sv.xy_m))
        assert res.relief_gain >= SmootherConfig().relief_min_gain, res.relief_gain
        height_errs.append(float(np.sqrt(np.mean((res.landmark_height_m - heights) ** 2))))
        truth_rms.append(float(np.sqrt(np.mean(heights**2))))
        assert np.all(flat.landmark_height_m == 0.0) and np.all(flat.seabed_m == 0.0)
    ratio = np.array(relief_ates) / np.array(flat_ates)
    print(
        f"\nrelief 3 cm, 6 runs: smoothed ATE flat {np.median(flat_ates) * 1e3:.2f} mm, with the heights "
        f"{np.median(relief_ates) * 1e3:.2f} mm (ratio median {np.median(ratio):.2f}, worst {ratio.max():.2f}); "
        f"heights off by {np.median(height_errs) * 100:.2f} cm RMS (truth {np.median(truth_rms) * 100:.2f} cm)"
    )
    # Measured (seeds 2000-2005): ATE 5.21 -> 3.93 mm, ratio 0.73 median, 0.78 worst; heights off by
    # 1.14 cm RMS against 2.61 cm of relief.
    assert np.median(ratio) < 0.8 and ratio.max() < 0.9
    assert np.median(height_errs) < 0.5 * np.median(truth_rms)


def test_on_a_flat_seabed_the_relief_rounds_are_set_aside():
    """On a flat seabed the heights and the seabed offset fit the pixel noise alone (a fifth of the misfit,
    the path then 14 % worse); below ``relief_min_gain`` the flat seabed's result is kept, as it was."""
    for seed in (1000, 1001, 12):
        sv = grid_survey(seed)
        _, _, flat = smooth(sv.frames, smoother_config(relief_rounds=0))
        _, _, res = smooth(sv.frames, smoother_config())
        assert math.isnan(flat.relief_gain) and 0.0 < res.relief_gain < SmootherConfig().relief_min_gain
        np.testing.assert_array_equal(res.xy_m, flat.xy_m)
        np.testing.assert_array_equal(res.cov_xy_m2, flat.cov_xy_m2)
        assert np.all(res.landmark_height_m == 0.0)


def test_the_relief_step_recovers_heights_and_seabed_exactly_from_exact_views():
    """solve_relief with the true poses and noise-free pixels: every observation's depth, the landmarks and
    their heights come back (the priors pull them by less than the tolerances)."""
    from rovslam.slam.heights import ReliefObservations, ReliefPriors, observation_depths, solve_relief

    rng = np.random.default_rng(4)
    n, m, z, f = 200, 12, 1.3, 1075.0
    t = np.arange(n) * 0.2
    xy = np.column_stack([np.linspace(0.0, 1.0, n), 0.05 * np.sin(t)])
    psi = 0.3 + 0.2 * np.sin(0.1 * t)
    seabed = 0.01 * np.sin(0.05 * t) - 0.01 * np.sin(0.05 * t[0])  # s_0 = 0: the datum
    lxy = np.column_stack([rng.uniform(0.0, 1.0, m), rng.uniform(-0.1, 0.1, m)])
    heights = rng.normal(0.0, 0.02, m)
    poses, lms, rays = [], [], []
    for k in range(n):
        rel = (lxy - xy[k]) @ rot2(psi[k])  # rows: R^T (X - x)
        for i in np.flatnonzero(np.all(np.abs(rel) < [0.12, 0.16], axis=1)):
            poses.append(k)
            lms.append(i)
            rays.append(rel[i] / (z + seabed[k] - heights[i]))  # [m, n] / f of (3)
    obs = ReliefObservations(
        pose=np.array(poses),
        landmark=np.array(lms),
        ray=np.array(rays),
        noise=np.tile(np.eye(2) * (0.3 / f) ** 2, (len(poses), 1, 1)),
        first_pose=np.array([poses[lms.index(i)] for i in range(m)]),
    )
    assert set(lms) == set(range(m)) and len(poses) > 20 * m
    altitude = np.full(n, z)
    sol = solve_relief(
        xy, psi, t, altitude, lxy + 0.01, np.full(len(poses), z), obs, ReliefPriors(0.03, 0.02, 5.0), "none", 3.0
    )  # least squares: the robust weights at this flat, 1 cm off start would down-weight every view
    # The images see the depths Z + s - h; a common shift of every height and of s after the start is
    # held only by s's process from the start's datum, so the heights are compared up to their mean.
    depth = observation_depths(altitude, sol.seabed_m, sol.height_m, obs)
    # Measured: median 0.03 mm, worst 1.0 mm (a landmark near the image centre: little parallax, its prior
    # pulls); heights to 0.6 mm, landmarks to 0.008 mm.
    err_m = np.abs(depth - (z + seabed[obs.pose] - heights[obs.landmark]))
    assert np.median(err_m) < 1e-4 and err_m.max() < 2e-3, (np.median(err_m), err_m.max())
    np.testing.assert_allclose(sol.height_m - sol.height_m.mean(), heights - heights.mean(), atol=1.5e-3)
    np.testing.assert_allclose(sol.landmarks_xy_m, lxy, atol=2e-5)


def test_a_wrong_association_over_relief_leaves_the_heights_in_and_the_path_close():
    """The relief's gain is counted over the observations it explains, so one wrong association (60-110 cm
    off), which neither model can fit, neither hides the relief nor is fitted by it. Measured (seeds
    2000-2003): gains unchanged (0.46-0.92), ATE 3.30 -> 3.67, 2.88 -> 3.23, 4.78 -> 5.26, 4.55 -> 2.71 mm."""
    for seed in (2000, 2001, 2002, 2003):
        sv, _ = relief_survey(seed)
        k, frames, _ = inject_wrong_association(sv.frames, sv.landmarks_xy_m)
        _, _, clean = smooth(sv.frames, smoother_config())
        _, _, res = smooth(frames, smoother_config())
        assert res.relief_gain >= SmootherConfig().relief_min_gain
        assert abs(res.relief_gain - clean.relief_gain) < 0.02, (res.relief_gain, clean.relief_gain)
        assert ate_m(res.xy_m, sv.xy_m) < 1.2 * ate_m(clean.xy_m, sv.xy_m)
        assert res.landmark_downweighted.sum() >= 1  # the wrong one is flagged
