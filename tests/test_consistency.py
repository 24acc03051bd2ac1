"""Acceptance of the consistency issue: wrong matches refused, faults recovered, no ambiguous landmarks.

* A landmark template pasted at another place (the true one hidden) is refused, however
  strong its correlation, and the estimate stays inside its bounds; one landmark alone never
  moves the filter, however long it persists (:class:`RecoveryMonitor` unit tests).
* A 10 cm odometry fault in one step is followed by a recovery event, and the truth is back
  inside the 2-sigma ellipse within 10 s of dive time.
* A self-similar template (a grating) is never made a landmark (the paper's choice, the
  highest local variance, makes it one).
* Three seeds of the real-photo survey with turns stay inside their 2-sigma ellipse on at
  least 95 % of the frames.
* In turbid water (laser spots read half a pixel inward: the altitude 1 % long for the whole
  dive; the compass drifting by 1 degree) the truth stays inside the 2-sigma ellipse.

The dives are simulated once per module (seeded). Frame numbers below are those of the
seeded dives: the fault is injected where the map seen before it comes back into view.
"""

from __future__ import annotations

import dataclasses
import math

import datasets
import numpy as np
import pytest
from synth import paper_camera, seabed_frame, seabed_spectrum, simulate_variant

from rovslam.config import AssociationConfig, RunConfig
from rovslam.core import Frame, SequenceInfo
from rovslam.io.sequence import open_sequence, read_groundtruth
from rovslam.mapping.association import RecoveryMonitor
from rovslam.pipeline import SlamPipeline
from rovslam.sim import simulate

TWO_SIGMA_NEES = 4.0  # inside the 2-sigma ellipse: Mahalanobis distance <= 2 (as `rovslam eval`)


# ----------------------------------------------------------------------------- the recovery monitor


def _monitor(**kw) -> RecoveryMonitor:
    return RecoveryMonitor(AssociationConfig(**kw))


def test_one_landmark_alone_never_triggers_a_recovery():
    mon = _monitor()
    offset = np.array([0.02, -0.01])
    for k in range(50):  # a look-alike: 10 s of the same strong refused match
        assert mon.refusals(0.2 * k, [offset], [7], accepted_older=False) is None
    assert mon.refused_streak == 50


def test_two_landmarks_telling_the_same_offset_trigger_it():
    mon = _monitor()
    offset = np.array([0.10, 0.0])
    assert mon.refusals(24.0, [offset], [9], False) is None  # landmark 9 refused, then lost from view
    for k in range(5):
        assert mon.refusals(24.2 + 0.2 * k, [], [], False) is None
    assert mon.refused_streak == 0
    assert mon.refusals(28.0, [offset + 0.002], [1], False) is None
    assert mon.refusals(28.2, [offset - 0.001], [1], False) is None
    got = mon.refusals(28.4, [offset + 0.001], [1], False)  # three frames in a row, two witnesses in 10 s
    assert got is not None and np.allclose(got, offset, atol=0.003)


def test_evidence_is_forgotten_after_the_memory_or_an_older_landmark_accepted():
    offset = np.array([0.10, 0.0])
    mon = _monitor(recovery_memory_s=5.0)
    mon.refusals(20.0, [offset], [9], False)
    for t in (28.0, 28.2, 28.4):  # 8 s later: landmark 9's word has expired
        assert mon.refusals(t, [offset], [1], False) is None
    mon = _monitor()
    mon.refusals(20.0, [offset], [9], False)
    mon.refusals(21.0, [], [], accepted_older=True)  # the estimate agrees with an older landmark
    for t in (22.0, 22.2, 22.4):
        assert mon.refusals(t, [offset], [1], False) is None


def test_offsets_that_disagree_are_no_evidence():
    mon = _monitor()
    assert mon.refusals(1.0, [np.array([0.05, 0.0]), np.array([-0.05, 0.0])], [1, 2], False) is None


def test_lost_landmarks_count_against_the_estimate():
    mon = _monitor(wide_search_after_frames=2)
    mon.wide_candidates([3, 4])
    for _ in range(3):
        mon.searched(3, False)  # landmark 3 expected in view, not found three frames in a row
    offset = np.array([0.0, 0.04])
    mon.wide_candidates([3, 4])
    assert mon.refusals(1.0, [offset], [4], False) is None
    assert mon.refusals(1.2, [offset], [4], False) is None
    assert mon.refusals(1.4, [offset], [4], False) is not None


def test_refusals_checks_its_arguments():
    from rovslam.errors import InvalidArgumentError

    with pytest.raises(InvalidArgumentError, match="2 offsets but 1 landmark"):
        _monitor().refusals(0.0, [np.zeros(2), np.zeros(2)], [1], False)


# ----------------------------------------------------------------------------- on a simulated dive


@pytest.fixture(scope="module")
def relief_dive(tmp_path_factory):
    """The paper's trial over relief with the vehicle's lamps, first 300 frames (60 s), seed 0."""
    root = tmp_path_factory.mktemp("consistency") / "portofino-relief"
    simulate("portofino-relief", root, frames=300, seed=0)
    return root


def without_widening_terms(cfg: RunConfig) -> RunConfig:
    """``cfg`` without the terms added after the slow negative controls were measured that widen a dive's ellipse.

    The relief off the laser spots' plane in the altitude and in the landmarks (``relief_altitude_gain``,
    ``landmark_relief_gain``), the laser rig's share of the depth in b (``altitude_scale_sigma``), the zoom
    between frames and the relief-weighted turn (``token_scale``, ``relief_turn_gain``). With them a control
    ("without this term the truth leaves the ellipse") no longer leaves it, so a check that a term is
    needed would not fail without it.
    """
    return dataclasses.replace(
        cfg,
        slam=dataclasses.replace(cfg.slam, altitude_scale_sigma=0.0, landmark_relief_gain=0.0),
        laser=dataclasses.replace(cfg.laser, relief_altitude_gain=0.0),
        odometry=dataclasses.replace(cfg.odometry, token_scale=False, relief_turn_gain=0.0),
    )


def _run(root, config: RunConfig | None = None, inject=None, speed_fault=None):
    """Run the pipeline over a dive; ``inject[k](frame) -> frame`` alters frame k's image,
    ``speed_fault = (k, jump_m)`` adds ``jump_m`` of surge to frame k's measured speed.

    Returns the pipeline, the results and the per-frame NEES of the 2-D position (0 at frame 0).
    """
    seq = open_sequence(root)
    gt = read_groundtruth(root / "groundtruth.csv")
    pipe = SlamPipeline(seq.info, config or RunConfig())
    if speed_fault is not None:
        measure, clock = pipe.speed.take, {"k": -1, "dt_s": 0.0}  # step 5's speed as it leaves the estimator

        def faulty(*args, **kwargs):
            m = measure(*args, **kwargs)
            if clock["k"] == speed_fault[0]:
                m = dataclasses.replace(m, surge_mps=m.surge_mps + speed_fault[1] / clock["dt_s"])
            return m

        pipe.speed.take = faulty
    results, nees, t_prev = [], [], 0.0
    for frame in seq.frames():
        if inject and frame.index in inject:
            frame = inject[frame.index](frame)
        if speed_fault is not None:
            clock.update(k=frame.index, dt_s=frame.t_s - t_prev)
            t_prev = frame.t_s
        r = pipe.process(frame)
        e = np.array([r.x_m - gt.x_m[frame.index], r.y_m - gt.y_m[frame.index]])
        nees.append(float(e @ np.linalg.solve(r.cov_xy_m2, e)) if frame.index else 0.0)
        results.append(r)
    return pipe, results, np.array(nees)


@pytest.fixture(scope="module")
def clean_run(relief_dive):
    return _run(relief_dive)


def test_the_clean_dive_is_consistent(clean_run):
    _, _, nees = clean_run
    assert np.mean(nees < TWO_SIGMA_NEES) >= 0.95


def _accepted(result, landmark_id: int) -> bool:
    return any(o.landmark_id == landmark_id and o.accepted for o in result.observations)


def _pasted_elsewhere(uv_px: np.ndarray, offset_px: tuple[int, int], half: int = 20):
    """Frame alteration: the seabed around ``uv_px`` copied ``offset_px`` away, its place hidden
    under seabed from 50 px above or below (a look-alike of the landmark, the landmark unseen)."""

    def alter(frame: Frame) -> Frame:
        img = frame.image.copy()
        u, v = np.round(uv_px).astype(int)
        du, dv = offset_px
        other = 50 if v < img.shape[0] / 2 else -50
        img[v - half : v + half, u - half : u + half] = frame.image[
            v - half + other : v + half + other, u - half : u + half
        ]
        img[v - half + dv : v + half + dv, u - half + du : u + half + du] = frame.image[
            v - half : v + half, u - half : u + half
        ]
        return dataclasses.replace(frame, image=img)

    return alter


@pytest.mark.parametrize("alone", [True, False], ids=["only-landmark-in-view", "with-others"])
def test_a_landmark_pasted_elsewhere_is_refused_and_the_estimate_stays_in_bounds(relief_dive, clean_run, alone):
    _, clean, clean_nees = clean_run
    n_wrong = 3  # frames in a row: as many as a recovery would need, were one landmark enough

    def found(k):
        """Confirmed landmarks accepted at k, k+1, k+2, far enough from the border to paste next to them."""
        out = []
        for o in clean[k].observations:
            u, v = o.uv_px
            if not (o.accepted and o.kind == "track" and not o.tentative and 60 < u < 300 and 60 < v < 212):
                continue
            if not all(_accepted(clean[j], o.landmark_id) for j in range(k, k + n_wrong)):
                continue
            n_seen = [len([p for p in clean[j].observations if p.kind == "track"]) for j in range(k, k + n_wrong)]
            if alone == all(n == 1 for n in n_seen):
                out.append(o.landmark_id)
        return out

    k0, lid = next((k, ids[0]) for k in range(20, len(clean) - 60) if (ids := found(k)))
    inject = {}
    for k in range(k0, k0 + n_wrong):
        uv = next(o.uv_px for o in clean[k].observations if o.landmark_id == lid)
        inject[k] = _pasted_elsewhere(uv, (6, 4))  # 7 px: about 9 mm at 1.31 m, inside the search window
    pipe, bad, nees = _run(relief_dive, inject=inject)
    for k in range(k0, k0 + n_wrong):
        (o,) = [o for o in bad[k].observations if o.landmark_id == lid]
        assert o.score > 0.9  # a correct-looking match ...
        assert not o.accepted and o.reason in ("innovation test", "joint compatibility")  # ... refused
    assert pipe.recovery.events == []
    after = slice(k0, k0 + 50)  # the next 10 s
    assert np.all(nees[after] < TWO_SIGMA_NEES)
    assert np.max(nees[after]) < np.max(clean_nees[after]) + 1.0


FAULT_FRAME = 120  # 24 s: a landmark mapped before is in view, others come back within seconds


def test_an_odometry_fault_is_followed_by_a_recovery_within_10_s(relief_dive, clean_run):
    pipe, results, nees = _run(relief_dive, speed_fault=(FAULT_FRAME, 0.10))
    t_fault = results[FAULT_FRAME].t_s
    assert nees[FAULT_FRAME] > 100.0  # the fault took the estimate 10 cm (about 20 sigma) away
    events = [e for e in pipe.recovery.events if e.t_s >= t_fault]
    assert events and events[0].t_s <= t_fault + 10.0
    assert np.hypot(*events[0].offset_m) == pytest.approx(0.10, abs=0.01)  # it told the fault's size
    outside = np.nonzero(nees[FAULT_FRAME:] >= TWO_SIGMA_NEES)[0] + FAULT_FRAME
    assert results[outside[-1]].t_s <= t_fault + 10.0  # back inside 2 sigma within 10 s, and for good
    assert results[-1].recovery is None and any(r.recovery is events[0] for r in results)  # an event of the run


def test_without_recovery_the_same_fault_stays_outside_the_bounds(relief_dive):
    cfg = RunConfig()
    cfg = dataclasses.replace(cfg, association=dataclasses.replace(cfg.association, recovery=False))
    pipe, _, nees = _run(relief_dive, cfg, speed_fault=(FAULT_FRAME, 0.10))
    assert pipe.recovery.events == []
    assert np.mean(nees[FAULT_FRAME:] >= TWO_SIGMA_NEES) > 0.5


# ----------------------------------------------------------------------------- unambiguous landmarks

GRATING_TEXTURE_UV = (250, 180)  # centre of a 56x56 px grating painted on the seabed (texture pixels)
GRATING_HALF_PX = 28


def _frames_over_a_grating(n: int, step_px: float = 3.0):
    """A vehicle moving forward over a seabed with a high-contrast grating (8 px period) in view.

    Window start (60, 120 - step k) of the texture: texture point (X, Y) is at image
    (X - 60, Y - 120 + step k). Returns the frames and the grating's centre in each.
    """
    spectrum = seabed_spectrum((512, 512), seed=5)
    frames, centres = [], []
    for k in range(n):
        img = seabed_frame(spectrum, (60.0, 120.0 - step_px * k), seed=k)
        cu = GRATING_TEXTURE_UV[0] - 60
        cv = GRATING_TEXTURE_UV[1] - 120 + step_px * k
        v0 = int(round(cv)) - GRATING_HALF_PX
        u0 = cu - GRATING_HALF_PX
        rows = np.arange(v0, v0 + 2 * GRATING_HALF_PX)
        ok = (rows >= 0) & (rows < img.shape[0])
        yy, xx = np.mgrid[0 : 2 * GRATING_HALF_PX, 0 : 2 * GRATING_HALF_PX]
        grating = (40 + 170 * (((xx // 8) + (yy // 8)) % 2)).astype(np.uint8)
        for c in range(3):
            img[rows[ok], u0 : u0 + 2 * GRATING_HALF_PX, c] = grating[ok]
        frames.append(Frame(index=k, t_s=0.2 * k, image=img, heading_rad=0.0))
        centres.append(np.array([cu, cv], dtype=float))
    return frames, centres


def _landmarks_created(config: RunConfig) -> list[tuple[int, np.ndarray, float]]:
    """(frame, template centre, ambiguity) of every landmark the pipeline creates over the grating dive."""
    info = SequenceInfo(name="grating", camera=paper_camera(), lasers=(), fixed_altitude_m=1.31)
    pipe = SlamPipeline(info, config)
    frames, _ = _frames_over_a_grating(30)
    created = []
    for frame in frames:
        for o in pipe.process(frame).observations:
            if o.kind == "init":
                created.append((frame.index, o.uv_px, _ambiguity(frame.image, o.uv_px)))
    return created


def _ambiguity(image: np.ndarray, uv_px: np.ndarray, half: int = 16, radius: int = 24, exclusion: int = 3) -> float:
    """Highest normalised correlation of the template at ``uv_px`` with the frame around it,
    more than ``exclusion`` px from itself: near 1, the template would be confused with its neighbour."""
    import cv2

    grey = image.astype(np.float32).mean(axis=2)
    u, v = np.round(uv_px).astype(int)
    template = grey[v - half : v + half, u - half : u + half]
    y0, x0 = max(v - half - radius, 0), max(u - half - radius, 0)
    region = grey[y0 : v + half + radius, x0 : u + half + radius]
    score = cv2.matchTemplate(region, template, cv2.TM_CCOEFF_NORMED)
    yy, xx = np.mgrid[0 : score.shape[0], 0 : score.shape[1]]
    self_yx = (v - half - y0, u - half - x0)
    far = np.maximum(np.abs(yy - self_yx[0]), np.abs(xx - self_yx[1])) > exclusion
    return float(score[far].max())


def test_a_self_similar_template_is_never_made_a_landmark():
    created = _landmarks_created(RunConfig())
    assert created  # landmarks are made, where they are unambiguous
    assert max(a for _, _, a in created) < 0.8


def test_without_the_self_similarity_test_the_grating_is_a_landmark():
    cfg = RunConfig()
    cfg = dataclasses.replace(cfg, association=dataclasses.replace(cfg.association, max_self_similarity=1.0))
    created = _landmarks_created(cfg)
    assert created and created[0][2] > 0.95  # the paper's choice, the highest variance: the grating


# ----------------------------------------------------------------------------- the real-photo survey with turns


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow)])
def test_the_real_photo_survey_with_turns_stays_inside_its_bounds(tmp_path, seed):
    """2 minutes (600 frames) of ``photo-turns`` (the chamber3 photomosaic, heading turns, yaw
    oscillation, tilt, compass noise): truth inside the 2-sigma ellipse on >= 95 % of frames.
    Seed 0 in ``make test``, seeds 1 and 2 in ``make test-all`` (about 20 s each)."""

    datasets.skip_unless("chamber3")
    simulate("photo-turns", tmp_path / "seq", frames=600, seed=seed)
    _, _, nees = _run(tmp_path / "seq")
    assert np.mean(nees < TWO_SIGMA_NEES) >= 0.95


@pytest.mark.slow  # two 600-frame runs, about 26 s of CPU: the term itself is checked in tests/test_apparent.py, in make test
def test_a_compass_deviation_stays_inside_the_bounds_it_is_given(tmp_path):
    """2 minutes of ``photo-survey`` under a compass that reads 1 degree high all dive (its
    deviation: the vehicle's own magnetism, a declination error). No image can see it: the whole
    estimate turns by it about the start. Told the compass's accuracy (``[odometry]
    compass_offset_sigma_rad = 0.0175``) the reported covariance carries that turn: measured
    97.2 % inside 2-sigma; without the term 83.2 %."""
    from rovslam.sim import SCENARIOS

    datasets.skip_unless("chamber3")
    nav = dataclasses.replace(SCENARIOS["photo-survey"].nav, compass_bias_rad=math.radians(1.0))
    simulate_variant(tmp_path / "seq", "photo-survey", "photo-survey-deviated", 0, n_frames=600, nav=nav)
    cfg = RunConfig()
    # b as it was when this was measured: the relief under the tokens in b (altitude_bias_relief) widens the
    # ellipse along the lanes, which on a grid covers the deviation's turn too (99.5 % without the term);
    # so does the laser rig's share of the depth in b (altitude_scale_sigma: 92.7 % without the term), and the relief
    # off the laser spots' plane in the altitude and the landmarks' observations (relief_altitude_gain,
    # landmark_relief_gain: 100 % without the term), and the zoom between frames with the relief-weighted
    # turn (token_scale, relief_turn_gain: 97.2 % without the term).
    cfg = without_widening_terms(cfg)
    cfg = dataclasses.replace(cfg, slam=dataclasses.replace(cfg.slam, altitude_bias_relief=False))

    def offset(sigma_rad: float) -> RunConfig:
        return dataclasses.replace(cfg, odometry=dataclasses.replace(cfg.odometry, compass_offset_sigma_rad=sigma_rad))

    _, _, nees = _run(tmp_path / "seq", offset(0.0175))
    assert np.mean(nees < TWO_SIGMA_NEES) >= 0.95
    _, _, nees_without = _run(tmp_path / "seq", offset(0.0))
    assert np.mean(nees_without < TWO_SIGMA_NEES) < 0.9


# ----------------------------------------------------------------------------- lasting calibration errors


def test_with_lasting_calibration_errors_the_ellipse_is_neither_too_narrow_nor_too_wide(tmp_path):
    """40 s (200 frames) of ``portofino-short``, seed 23, with the seed's calibration errors drawn (a
    compass deviation, a laser-rig baseline error, a sonar offset: ``rovslam simulate
    --calibration-errors``), the lasting errors the filter's covariance allows for. Coverage alone is
    checked from below, so an ellipse ten times too wide would pass it; the mean NEES (2 for a
    consistent 2-D estimate) is checked from both sides: about 0.3 to 2.

    Measured (mean NEES over frames 1-199 of the dive with the errors drawn; ``simulate``, then the
    pipeline, NEES from the written covariances): seed 23 (compass +0.80 degree, rig +0.28 %, sonar
    +2.15 cm) 0.79 (0.74 over 150 frames, 0.89 over 500), 100 % inside 2-sigma. Seed 20 (rig +0.80 %,
    compass -0.03 degree, sonar +0.57 cm) 0.52, also inside (a second seed would double the 10 s of
    CPU). The seeds drawing errors well under one sigma give a conservative ellipse, as they should:
    seed 21 0.11, seed 22 0.28, seed 24 0.17 over the same 200 frames.
    """
    from rovslam.sim import CalibrationErrors

    simulate("portofino-short", tmp_path / "seq", frames=200, seed=23, calibration=CalibrationErrors())
    _, _, nees = _run(tmp_path / "seq")
    assert np.mean(nees < TWO_SIGMA_NEES) >= 0.95
    assert 0.3 <= float(np.mean(nees[1:])) <= 2.0, float(np.mean(nees[1:]))


# ----------------------------------------------------------------------------- turbid water


def _earlier_filter() -> RunConfig:
    """The filter before the altitude offset became a lasting consider state (issue 10's first build)."""
    cfg = RunConfig()
    return dataclasses.replace(
        cfg,
        slam=dataclasses.replace(
            cfg.slam, altitude_bias_consider=False, altitude_bias_tau_s=1.0, heading_bias_sigma_rad=0.0087
        ),
        odometry=dataclasses.replace(cfg.odometry, compass_drift_sigma_rad=0.0087),
    )


def _thresholded_spots(cfg: RunConfig) -> RunConfig:
    """The laser spots' centres from their thresholded pixels only (before ``[laser] spot_skirt_px``)."""
    return dataclasses.replace(cfg, laser=dataclasses.replace(cfg.laser, spot_skirt_px=0.0))


def _ate_m(results, root) -> float:
    gt = read_groundtruth(root / "groundtruth.csv")
    e = np.array([[r.x_m - gt.x_m[i], r.y_m - gt.y_m[i]] for i, r in enumerate(results)])
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def test_turbid_water_first_40_s_stay_inside_their_bounds(tmp_path):
    """The slow turbid-water test below on its first 40 s (200 frames of ``turbid-relief``, seed 0):
    the default inside 2-sigma, and with the thresholded laser-spot centres (the altitude read
    0.8 % long all dive) inside 2-sigma with a mean NEES in a band, both sides.

    Measured (this dive and :func:`_run`, frames 1-199): default 100 % inside, mean NEES 0.17, ATE
    2.8 mm; thresholded 100 %, NEES 0.51, ATE 5.9 mm (the earlier filter, not run here: 100 %, NEES
    1.01; over 300 frames 89.0 %, and over the slow test's 750 frames the thresholded NEES reaches
    1.05). The band is 2.5 times the measured 0.51 either way; the ATE ratio, 0.48, is bounded as
    the slow test bounds it.
    """
    seq = tmp_path / "seq"
    simulate("turbid-relief", seq, frames=200, seed=0)
    _, results, nees = _run(seq)
    assert np.mean(nees < TWO_SIGMA_NEES) >= 0.95
    _, results_long, nees_long = _run(seq, _thresholded_spots(RunConfig()))
    assert np.mean(nees_long < TWO_SIGMA_NEES) >= 0.95
    assert 0.2 <= float(np.mean(nees_long[1:])) <= 1.3, float(np.mean(nees_long[1:]))
    assert _ate_m(results, seq) < 0.85 * _ate_m(results_long, seq)


@pytest.mark.slow
def test_turbid_water_stays_inside_its_bounds(tmp_path):
    """2.5 minutes of ``turbid-relief`` seed 0: >= 95 % inside 2-sigma, with and without a lasting
    altitude error.

    The H.264 round trip of this water smears the laser spots lopsidedly: their thresholded pixels
    sit 0.5 px inward (the altitude reads 1.1 cm, 0.8 %, long for the whole dive); the default centre
    (``spot_skirt_px``) is 0.02 px off. Measured, default: ATE 2.3 mm, 100 % inside, NEES 0.28 (the
    1-cm altitude offset and the 1-degree compass drift in the covariance are larger than this
    dive's errors: conservative). With the thresholded centres, an error that lasts: ATE 4.7 mm,
    96.1 %, NEES 1.05 (2026-12-07, the filter pinned as it was then: 3.9 mm, 95.3 %, NEES 1.05); the earlier filter (the altitude offset learned with a 1 s correlation, a
    0.5 degree compass drift) 62.9 %, NEES 4.2 on the same frames.
    """
    seq = tmp_path / "seq"
    simulate("turbid-relief", seq, frames=750, seed=0)

    def as_measured(cfg: RunConfig) -> RunConfig:
        # The filter as it was when this was measured: no faint laser spots looked for near their prediction
        # (faint_red_excess), no laser rig's share of the depth in b (altitude_scale_sigma). Both widen what the
        # filter expects of a lasting altitude error like the thresholded centres' (with them: 99.1 % inside,
        # NEES 0.70, consistent but more conservative than the 1 to 3 asked of it here).
        return dataclasses.replace(
            cfg,
            laser=dataclasses.replace(cfg.laser, faint_red_excess=0.0),
            slam=dataclasses.replace(cfg.slam, altitude_scale_sigma=0.0),
        )

    _, results, nees = _run(seq, as_measured(RunConfig()))
    assert np.mean(nees < TWO_SIGMA_NEES) >= 0.95
    _, results_long, nees_long = _run(seq, as_measured(_thresholded_spots(RunConfig())))
    assert np.mean(nees_long < TWO_SIGMA_NEES) >= 0.95
    assert 1.0 <= float(np.mean(nees_long[1:])) <= 3.0
    assert _ate_m(results, seq) < 0.85 * _ate_m(results_long, seq)
    _, _, nees_before = _run(seq, as_measured(_thresholded_spots(_earlier_filter())))
    assert np.mean(nees_before < TWO_SIGMA_NEES) < 0.8
