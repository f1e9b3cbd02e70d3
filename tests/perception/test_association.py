"""Lost-mug association (§4.1, §4.3.1): known within 1 cm, the target by type and distance, rest optimally."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from perception.assignment import least_cost_assignment
from perception.association import associate
from perception.interfaces import Detection


def mug(x: float, y: float, type_: str = "big", mug_id: str = "") -> Detection:
    return Detection(type_, x, y, False, 0.0, 0.9, mug_id)


KNOWN = [mug(0.0, 0.40, "big", "m1"), mug(0.15, 0.40, "small", "m2"), mug(0.30, 0.40, "big", "m3")]


def test_mugs_within_a_centimetre_keep_their_ids_and_stored_positions() -> None:
    seen = [mug(0.004, 0.405), mug(0.147, 0.398, "small"), mug(0.30, 0.392)]
    result = associate(KNOWN, seen)
    assert [d.mug_id for d in result] == ["m1", "m2", "m3"]
    assert [(d.x_m, d.y_m) for d in result] == [(k.x_m, k.y_m) for k in KNOWN]
    assert result.kept == ("m1", "m2", "m3")
    assert not result.count_changed


def test_a_mug_that_has_not_moved_keeps_the_handle_seen_before_when_it_is_hidden_now() -> None:
    known = [replace(KNOWN[0], handle_yaw_rad=1.2), replace(KNOWN[1], handle_yaw_rad=0.3, handle_seen=False)]
    seen = [
        replace(mug(0.004, 0.405), handle_yaw_rad=-2.0, handle_seen=False),
        replace(mug(0.147, 0.398, "small"), handle_yaw_rad=0.5),
    ]
    first, second = associate(known, seen)
    assert (first.mug_id, first.handle_yaw_rad, first.handle_seen) == ("m1", 1.2, True)
    assert (second.mug_id, second.handle_yaw_rad, second.handle_seen) == ("m2", 0.5, True)


def test_the_dropped_target_is_the_unknown_mug_of_its_type_closest_to_the_robot() -> None:
    # m3 slipped out of the gripper; two big mugs are now unknown: m1 was nudged, m3 lies nearer the robot.
    seen = [mug(0.06, 0.46), mug(0.15, 0.40, "small"), mug(0.10, 0.20)]
    result = associate(KNOWN, seen, target_id="m3", robot_xy=(0.0, 0.0))
    ids = {d.mug_id: (d.x_m, d.y_m) for d in result}
    assert ids["m3"] == (0.10, 0.20)
    assert ids["m1"] == (0.06, 0.46)
    assert set(result.moved) == {"m1", "m3"}
    assert result.kept == ("m2",)


def test_a_lone_unknown_mug_is_the_mug_that_moved() -> None:
    seen = [mug(0.0, 0.40), mug(0.15, 0.40, "small"), mug(0.22, 0.31)]
    result = associate(KNOWN, seen)
    assert [d.mug_id for d in result] == ["m1", "m2", "m3"]
    assert result.moved == ("m3",)
    assert (result[2].x_m, result[2].y_m) == (0.22, 0.31)


def test_the_rest_are_assigned_optimally_where_greedy_matching_would_cross() -> None:
    known = [mug(0.0, 0.0, "big", "a"), mug(0.2, 0.0, "big", "b")]
    seen = [mug(0.11, 0.0), mug(0.31, 0.0)]
    # Greedy takes the closest pair first (b with the mug at 0.11) and must then pair a with 0.31.
    result = associate(known, seen)
    assert [d.mug_id for d in result] == ["a", "b"]


def test_a_mug_is_never_matched_to_a_known_mug_of_another_type() -> None:
    known = [mug(0.0, 0.4, "big", "m1")]
    result = associate(known, [mug(0.0, 0.4, "small")])
    assert result[0].mug_id == ""
    assert result.lost == ("m1",)
    assert [d.type for d in result.new] == ["small"]


def test_a_missing_mug_is_lost_and_the_count_change_asks_for_a_replan() -> None:
    result = associate(KNOWN, [mug(0.0, 0.40), mug(0.30, 0.40)])
    assert result.lost == ("m2",)
    assert result.count_changed


def test_a_mug_far_from_every_known_one_is_new() -> None:
    result = associate(KNOWN, [*KNOWN, mug(-0.3, 0.5, "small")])
    assert result.new == (mug(-0.3, 0.5, "small"),)
    assert result.lost == ()
    assert result.count_changed


def test_known_mugs_without_unique_ids_are_refused() -> None:
    with pytest.raises(ValueError, match=r"^known mugs need unique, non-empty ids, got \['m1', 'm1'\]$"):
        associate([mug(0, 0, "big", "m1"), mug(1, 0, "big", "m1")], [])


def test_a_target_that_is_not_known_is_refused() -> None:
    with pytest.raises(
        ValueError, match=r"^target_id 'm9' is not among the known mugs \['m1', 'm2', 'm3'\]$"
    ):
        associate(KNOWN, [], target_id="m9")


points = st.lists(
    st.tuples(st.floats(-0.5, 0.5), st.floats(0.0, 0.6), st.sampled_from(["big", "small"])), max_size=7
)


@settings(max_examples=60, deadline=None)
@given(points, points)
def test_association_is_one_to_one_and_keeps_types(
    known_pts: list[tuple[float, float, str]], seen_pts: list[tuple[float, float, str]]
) -> None:
    known = [mug(x, y, t, f"k{i}") for i, (x, y, t) in enumerate(known_pts)]
    seen = [mug(x, y, t) for x, y, t in seen_pts]
    result = associate(known, seen)
    assert len(result) == len(seen)
    ids = [d.mug_id for d in result if d.mug_id]
    assert len(ids) == len(set(ids))
    assert sorted(ids + list(result.lost)) == sorted(k.mug_id for k in known)
    by_id = {k.mug_id: k for k in known}
    for d, s in zip(result, seen, strict=True):
        assert d.type == s.type
        if d.mug_id:
            assert by_id[d.mug_id].type == d.type
            assert math.hypot(by_id[d.mug_id].x_m - s.x_m, by_id[d.mug_id].y_m - s.y_m) <= 0.5
    assert len(result.new) == len(seen) - len(ids)


@settings(max_examples=400, deadline=None)
@given(
    shape=st.tuples(st.integers(1, 7), st.integers(1, 7)),
    values=st.lists(st.sampled_from([0.0, 1.0, 2.0, 0.25]) | st.floats(0.0, 1.0), min_size=49, max_size=49),
)
def test_the_assignment_is_scipys_to_the_pair_ties_and_tall_matrices_included(
    shape: tuple[int, int], values: list[float]
) -> None:
    """The optimal assignment without SciPy (whose import cost the daemon's loop 0.9 s): the same pairs,
    also where several assignments cost the same."""
    rows, cols = shape
    cost = np.array(values[: rows * cols]).reshape(rows, cols)
    expected = linear_sum_assignment(cost)
    assert least_cost_assignment(cost.tolist()) == list(zip(*(a.tolist() for a in expected), strict=True))
