"""The association's decision per match (rovslam.mapping.association.associate) on plain data: every reason kept,
and what each refusal counts for."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovslam.mapping.association import (
    REASON_GATE,
    REASON_JOINT,
    REASON_LASER,
    MatchCandidate,
    associate,
    strong_refusals,
    told_offset_m,
)


def _updated(landmark_id: int, accepted: bool, nis: float, *, confirmed: bool = True, score: float = 0.95):
    return MatchCandidate(landmark_id, confirmed, score, "", True, accepted, nis, np.array([3.0, -4.0]))


def test_each_match_gets_its_decision_and_reason_in_order():
    cands = [
        _updated(0, True, 1.2),
        _updated(1, False, 31.0),
        MatchCandidate(2, True, 0.9, REASON_JOINT),
        MatchCandidate(3, False, 0.9, REASON_LASER),
        _updated(4, True, 0.4, confirmed=False),
    ]
    d = associate(cands)
    assert [x.landmark_id for x in d] == [0, 1, 2, 3, 4]
    assert [x.accepted for x in d] == [True, False, False, False, True]
    assert [x.reason for x in d] == ["", REASON_GATE, REASON_JOINT, REASON_LASER, ""]
    assert [x.nis for x in d[:2]] == [1.2, 31.0] and math.isnan(d[2].nis) and math.isnan(d[3].nis)
    assert [x.tentative for x in d] == [False, False, False, True, True]
    # A laser spot inside the template says nothing of the landmark: neither counted nor searched.
    assert [x.counts_observation for x in d] == [True, True, True, False, True]
    assert [x.counts_search for x in d] == [True, True, True, False, True]


def test_strong_refusals_are_the_confirmed_refused_matches_with_a_high_correlation():
    cands = [
        _updated(5, False, 40.0),  # strong, confirmed, refused: evidence
        _updated(6, False, 40.0, score=0.5),  # weak correlation: no evidence
        _updated(7, False, 40.0, confirmed=False),  # tentative: no evidence
        MatchCandidate(8, True, 0.99, REASON_JOINT),  # refused before the test: no innovation
        _updated(9, True, 1.0),  # accepted, younger than landmark 5
    ]
    strong, older = strong_refusals(cands, 0.9)
    assert strong == [0] and older is False
    # An older confirmed landmark accepted in the same frame: the refused ones are the suspects.
    strong, older = strong_refusals([_updated(2, True, 1.0)] + cands, 0.9)
    assert strong == [1] and older is True
    assert strong_refusals([_updated(1, True, 1.0)], 0.9) == ([], False)


def test_told_offset_is_the_innovation_back_to_the_seabed_and_the_world_frame():
    # 500 px focal length, landmark 1.5 m below the camera, heading 90 degrees: [m, n] = (3, -4) px
    # is 9 mm forward, -12 mm starboard; the vehicle offset that explains it points the other way.
    off = told_offset_m(np.array([3.0, -4.0]), 1.5, math.pi / 2, 500.0)
    assert off == pytest.approx([-0.012, -0.009], abs=1e-12)
