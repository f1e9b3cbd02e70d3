"""Strays, mugs lying on the tray where no plan put them (``Problem.strays``): the problem format carries them
(only when there are any), and every placer keeps clear of them. Checked with shapely (mug outlines) and
rectangle intersection, independently of the placers' own geometry."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point

from planning.placement import InvalidProblem, PlanOptions, Problem, TrayStray, dataset_problem, plan
from planning.placement.shapes import MugOutline
from tests.planning.placement.test_mug_footprint import assert_valid_layout, outline_parts


def _robot_tray(footprint: str) -> Problem:
    return replace(dataset_problem(1), footprint_kind=footprint)


def test_the_problem_format_carries_strays_only_when_there_are_any() -> None:
    p = _robot_tray("mug")
    assert "strays" not in p.to_json()
    q = replace(
        p, strays=(TrayStray("s1", "big", (-20.5, 100.0), 0.3), TrayStray("s2", "small", (50.0, 60.0)))
    )
    doc = q.to_json()
    assert doc["strays"] == [
        {"id": "s1", "type": "big", "brim_mm": [-20.5, 100.0], "handle_yaw_rad": 0.3},
        {"id": "s2", "type": "small", "brim_mm": [50.0, 60.0]},
    ]
    assert Problem.from_json(doc) == q


@pytest.mark.parametrize(
    ("stray", "message"),
    [
        ({"id": "s1", "type": "tiny", "brim_mm": [1, 2]}, "strays[0].type: unknown mug type 'tiny'"),
        ({"id": "m1", "type": "big", "brim_mm": [1, 2]}, "strays[0].id: duplicate mug id 'm1'"),
        ({"id": "s1", "type": "big", "brim_mm": [1]}, "strays[0].brim_mm"),
        ({"id": "s1", "type": "big"}, "strays[0]"),
        ({"id": "", "type": "big", "brim_mm": [1, 2]}, "strays[0].id"),
    ],
)
def test_a_bad_stray_is_refused_with_one_line_naming_it(stray: dict[str, object], message: str) -> None:
    doc = _robot_tray("mug").to_json() | {"strays": [stray]}
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json(doc)
    assert str(e.value).startswith(message)
    assert "\n" not in str(e.value)


def test_a_stray_s_rectangle_is_its_whole_sweep_cut_to_the_tray() -> None:
    p = _robot_tray("rect")
    big = p.mug_types["big"]
    half = big.width_mm - big.diameter_mm / 2 + p.tolerance_mm / 2
    inside = replace(p, strays=(TrayStray("s", "big", (150.0, 150.0)),))
    x = math.floor(150 - half)
    assert inside.obstacle_rects() == [(x, x, math.ceil(150 + half) - x, math.ceil(150 + half) - x)]
    corner = replace(p, strays=(TrayStray("s", "big", (-10.0, -10.0)),))
    assert corner.obstacle_rects() == [(0, 0, math.ceil(-10 + half), math.ceil(-10 + half))]
    assert replace(p, strays=(TrayStray("s", "big", (-500.0, 0.0)),)).obstacle_rects() == []


def _rects_overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 9), st.floats(-30, 30), st.floats(-30, 30))
def test_the_rectangle_placer_keeps_clear_of_a_stray(k: int, dx: float, dy: float) -> None:
    p = _robot_tray("rect")
    options = PlanOptions(method="bh")
    free = plan(p, options)
    spot = free.placed[k % len(free.placed)]
    brim = p.brim_centre_on_tray(spot.type, spot.x_mm, spot.y_mm)
    q = replace(p, strays=(TrayStray("s", spot.type, (brim[0] + dx, brim[1] + dy)),))
    (stray,) = q.obstacle_rects()
    result = plan(q, options)
    assert result.placed
    for m in result.placed:
        assert not _rects_overlap((m.x_mm, m.y_mm, *q.footprint(m.type, m.rotated)), stray)


def _gap_to_stray(
    problem: Problem, stray: TrayStray, type_name: str, brim: tuple[float, float], yaw: float
) -> float:
    """The least distance from a placed outline to the stray: to its outline where its handle was seen, else
    to the disc its brim and handle sweep."""
    point, r, bar, t = outline_parts(problem, type_name, brim, yaw)
    o = MugOutline.of(problem.mug_types[stray.type])
    centre = Point(stray.brim_mm)
    if stray.handle_yaw_rad is None:
        reach = o.handle_to + o.half_thickness
        return min(point.distance(centre) - r, bar.distance(centre) - t) - reach
    _, sr, sbar, st_ = outline_parts(problem, stray.type, stray.brim_mm, stray.handle_yaw_rad)
    assert isinstance(sbar, LineString)
    return min(
        point.distance(centre) - r - sr,
        point.distance(sbar) - r - st_,
        bar.distance(centre) - t - sr,
        bar.distance(sbar) - t - st_,
    )


@settings(max_examples=6, deadline=None)
@given(st.integers(0, 9), st.one_of(st.none(), st.floats(-math.pi, math.pi)))
def test_the_mug_shaped_placer_keeps_clear_of_a_stray(k: int, yaw: float | None) -> None:
    p = _robot_tray("mug")
    options = PlanOptions(method="bh")
    free = plan(p, options)
    spot = free.placed[k % len(free.placed)]
    assert spot.brim_mm is not None
    stray = TrayStray("s", spot.type, spot.brim_mm, yaw)
    q = replace(p, strays=(stray,))
    result = plan(q, options)
    assert result.placed
    assert_valid_layout(q, result)
    o = MugOutline.of(q.mug_types[stray.type])
    # Unseen, the handle is kept clear in 32 directions: between two of them the sweep's edge comes this
    # much closer than the clearance.
    slack = 0.0 if yaw is not None else max(0.0, o.handle_to * math.sin(math.pi / 32) - o.half_thickness)
    for m in result.placed:
        assert m.brim_mm is not None
        assert m.handle_yaw_rad is not None
        assert _gap_to_stray(q, stray, m.type, m.brim_mm, m.handle_yaw_rad) >= q.tolerance_mm - slack - 1e-6
