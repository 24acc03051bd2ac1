"""Landmark labels never overlap, however crowded the landmarks (the issue's "0" and "1" read as "10")."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rovslam.viz.labels import place_labels
from rovslam.viz.plots import nice_scale


def _boxes(centres, sizes):
    return np.column_stack([centres - sizes / 2, centres + sizes / 2])


def _pairwise_overlap(boxes: np.ndarray) -> int:
    n = 0
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            n += bool(a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])
    return n


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 40), spread=st.floats(0.0, 300.0))
def test_labels_never_overlap_each_other_nor_cover_a_landmark(seed, n, spread):
    rng = np.random.default_rng(seed)
    anchors = rng.uniform(0, spread, (n, 2)) + 400.0
    sizes = np.column_stack([rng.uniform(6, 20, n), np.full(n, 10.0)])
    centres, moved = place_labels(anchors, sizes)
    boxes = _boxes(centres, sizes)
    assert _pairwise_overlap(boxes) == 0
    inside = (
        (anchors[:, None, 0] > boxes[None, :, 0])
        & (anchors[:, None, 0] < boxes[None, :, 2])
        & (anchors[:, None, 1] > boxes[None, :, 1])
        & (anchors[:, None, 1] < boxes[None, :, 3])
    )
    assert not inside.any()
    assert moved.dtype == bool and moved.shape == (n,)


def test_two_landmarks_a_pixel_apart_get_separate_labels_next_to_their_points():
    anchors = np.array([[100.0, 100.0], [101.0, 100.0]])
    sizes = np.array([[7.0, 10.0], [7.0, 10.0]])
    centres, moved = place_labels(anchors, sizes)
    assert _pairwise_overlap(_boxes(centres, sizes)) == 0
    # both stay within a couple of label heights of their landmark
    assert np.all(np.linalg.norm(centres - anchors, axis=1) < 30.0)
    assert not moved[0]


def test_labels_stay_inside_the_bounds_while_there_is_room():
    anchors = np.array([[2.0, 2.0], [198.0, 198.0]])
    sizes = np.full((2, 2), 10.0)
    centres, _ = place_labels(anchors, sizes, bounds_px=(0, 0, 200, 200))
    b = _boxes(centres, sizes)
    assert b[:, :2].min() >= 0 and b[:, 2:].max() <= 200


def test_ellipse_magnification_is_a_stated_1_2_5_number():
    assert [nice_scale(v) for v in (0.5, 1.0, 3.0, 7.9, 19.0, 49.0, 120.0)] == [1, 1, 2, 5, 10, 20, 100]


def test_refused_matches_are_grouped_by_the_reason_recorded():
    from rovslam.viz.plots import refusal_groups

    reasons = np.array(
        [
            "",
            "laser spot inside the template",
            "innovation test",
            "laser spot inside the template",
            "",
            "joint compatibility",
        ],
        dtype=object,
    )
    accepted = np.array([1, 0, 0, 0, 1, 0])
    groups = refusal_groups(reasons, accepted)
    assert [r for r, _ in groups][0] == "laser spot inside the template"  # the most frequent first
    assert {r: int(m.sum()) for r, m in groups} == {
        "laser spot inside the template": 2,
        "innovation test": 1,
        "joint compatibility": 1,
    }
    assert not any(m[0] or m[4] for _, m in groups)  # accepted matches are in no group
    assert refusal_groups(reasons, np.ones(6)) == []
