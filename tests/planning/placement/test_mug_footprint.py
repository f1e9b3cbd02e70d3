"""Mug-shaped footprints: outlines, the handle yaw the arm gives, the packer and the planner on them.

Overlap and wall checks are made with shapely (exact distances between the brim points and handle segments),
independently of the numpy geometry the planner packs with."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, box

from perception.assignment import least_cost_assignment
from planning.placement import (
    CounterMug,
    InvalidProblem,
    PlanOptions,
    PlanResult,
    Problem,
    TrayMug,
    dataset_problem,
    plan,
)
from planning.placement.mugpack import SCANS, MugPacker
from planning.placement.mugshaped import area_bound
from planning.placement.problem import default_mug_types
from planning.placement.shapes import MugOutline

TYPES = default_mug_types()


def outline_parts(
    problem: Problem, type_name: str, brim: tuple[float, float], yaw: float
) -> tuple[Point, float, LineString, float]:
    o = MugOutline.of(problem.mug_types[type_name])
    c, s = math.cos(yaw), math.sin(yaw)
    bar = LineString(
        [
            (brim[0] + o.handle_from * c, brim[1] + o.handle_from * s),
            (brim[0] + o.handle_to * c, brim[1] + o.handle_to * s),
        ]
    )
    return Point(brim), o.radius, bar, o.half_thickness


def assert_valid_layout(problem: Problem, result: PlanResult) -> None:
    """Every placed outline (and every mug already on the tray) half the clearance inside the walls and the
    clearance apart from every other, measured with shapely."""
    c = float(problem.tolerance_mm)
    tx, ty = problem.tray_size_mm
    inner = box(c / 2, c / 2, tx - c / 2, ty - c / 2)
    parts = []
    for q in problem.placed:
        parts.append(
            outline_parts(
                problem, q.type, problem.brim_centre_on_tray(q.type, q.x_mm, q.y_mm), q.handle_yaw()
            )
        )
    for p in result.placed:
        assert p.brim_mm is not None
        assert p.handle_yaw_rad is not None
        assert p.brim_mm == pytest.approx(problem.brim_centre_on_tray(p.type, p.x_mm, p.y_mm))
        parts.append(outline_parts(problem, p.type, p.brim_mm, p.handle_yaw_rad))
    for point, r, bar, t in parts[len(problem.placed) :]:
        assert inner.contains(point)
        assert inner.exterior.distance(point) >= r - 1e-6
        assert inner.contains(bar)
        assert inner.exterior.distance(bar) >= t - 1e-6
    for (p1, r1, b1, t1), (p2, r2, b2, t2) in itertools.combinations(parts, 2):
        gap = min(
            p1.distance(p2) - r1 - r2,
            p1.distance(b2) - r1 - t2,
            b1.distance(p2) - t1 - r2,
            b1.distance(b2) - t1 - t2,
        )
        assert gap >= c - 1e-6


counter_mugs = st.lists(
    st.tuples(
        st.sampled_from(sorted(TYPES)),
        st.floats(-450, 450),
        st.floats(370, 600),
        st.one_of(st.none(), st.floats(-math.pi, math.pi)),
    ),
    min_size=1,
    max_size=9,
)


def mug_problem(
    size: tuple[int, int], tolerance: int, mugs: list[tuple[str, float, float, float | None]]
) -> Problem:
    return Problem(
        tray_size_mm=size,
        tray_origin_mm=(340.0, -size[1] / 2),
        mugs=tuple(CounterMug(f"m{i}", t, x, y, yaw) for i, (t, x, y, yaw) in enumerate(mugs)),
        tolerance_mm=tolerance,
        footprint_kind="mug",
    )


@settings(max_examples=40, deadline=None)
@given(
    size=st.tuples(st.integers(140, 340), st.integers(140, 380)),
    tolerance=st.integers(0, 20),
    mugs=counter_mugs,
    sequence_seed=st.integers(0, 1000),
    scan=st.sampled_from(SCANS),
)
@pytest.mark.slow
def test_packed_outlines_never_overlap_and_stay_inside_the_tray(
    size: tuple[int, int],
    tolerance: int,
    mugs: list[tuple[str, float, float, float | None]],
    sequence_seed: int,
    scan: tuple[int, float, int],
) -> None:
    problem = mug_problem(size, tolerance, mugs)
    packer = MugPacker(problem)
    sequence = sorted(packer.class_of, key=lambda k: (k * 7919 + sequence_seed) % 13)
    spots = packer.pack(sequence, scan)
    placed = []
    for k, x, y in spots:
        c = packer.classes[k]
        brim = problem.brim_centre_on_tray(c.type, x, y)
        placed.append(outline_parts(problem, c.type, brim, packer.yaw_at(k, x, y)))
    half = tolerance / 2.0
    inner = box(half, half, size[0] - half, size[1] - half)
    for point, r, bar, t in placed:
        assert inner.exterior.distance(point) >= r - 1e-6
        assert inner.contains(point)
        assert inner.exterior.distance(bar) >= t - 1e-6
        assert inner.contains(bar)
    for (p1, r1, b1, t1), (p2, r2, b2, t2) in itertools.combinations(placed, 2):
        gap = min(
            p1.distance(p2) - r1 - r2,
            p1.distance(b2) - r1 - t2,
            b1.distance(p2) - t1 - r2,
            b1.distance(b2) - t1 - t2,
        )
        assert gap >= tolerance - 1e-6


@settings(max_examples=12, deadline=None)
@given(
    tolerance=st.integers(4, 16),
    mugs=counter_mugs,
    fixed_at=st.lists(st.tuples(st.integers(0, 230), st.integers(0, 270)), max_size=3),
)
@pytest.mark.slow
def test_planned_mugs_keep_clear_of_each_other_and_of_the_mugs_already_on_the_tray(
    tolerance: int, mugs: list[tuple[str, float, float, float | None]], fixed_at: list[tuple[int, int]]
) -> None:
    base = mug_problem((332, 374), tolerance, mugs)
    placed: list[TrayMug] = []
    for i, (x, y) in enumerate(fixed_at):
        candidate = TrayMug(f"p{i}", "small", x, y, handle_yaw_rad=0.3 * i)
        try:
            replace(base, placed=(*placed, candidate))
        except InvalidProblem:
            continue  # outside the tray or too close to one kept before
        placed.append(candidate)
    problem = replace(base, placed=tuple(placed))
    result = plan(problem, PlanOptions(method="bh", time_limit_s=0.05))
    assert_valid_layout(problem, result)
    assert {p.id for p in result.placed} | set(result.unplaced) == {m.id for m in problem.mugs}


@pytest.mark.parametrize("n", [1, 2, 3])
@pytest.mark.slow
def test_mug_shapes_place_more_than_the_rectangle_optimum_on_the_robot_tray(n: int) -> None:
    rect_problem = dataset_problem(n)
    rect = plan(rect_problem, PlanOptions())
    problem = replace(rect_problem, footprint_kind="mug")
    mug = plan(problem, PlanOptions())
    assert mug.n > rect.n
    assert_valid_layout(problem, mug)
    assert mug.upper_bound == area_bound(problem) >= mug.n
    assert mug.notes[0].startswith(f"mug-shaped: {rect.n} from the rectangle layout, {mug.n} after ")


# Issue 24's targets (10 mm clearance, handles as the arm turns them) where the placer reaches them at seed 0:
# 12 on dataset 1 is not reached (11; docs/placement.md says why).
MUG_COUNTS = {1: 11, 2: 11, 3: 12, 4: 23, 5: 25, 6: 26}


@pytest.mark.parametrize("n", sorted(MUG_COUNTS))
@pytest.mark.slow
def test_mug_shapes_reach_the_counts_of_issue_24_on_every_dataset(n: int) -> None:
    rect_problem = dataset_problem(n)
    problem = replace(rect_problem, footprint_kind="mug")
    # A generous budget: the fixed number of packings decides, not this machine's speed.
    mug = plan(problem, PlanOptions(time_limit_s=10.0))
    assert mug.n >= max(MUG_COUNTS[n], plan(rect_problem, PlanOptions()).n)
    assert_valid_layout(problem, mug)


@pytest.mark.slow
def test_a_seed_repeats_a_mug_shaped_plan_exactly() -> None:
    problem = replace(dataset_problem(2), footprint_kind="mug")
    a = plan(problem, PlanOptions(seed=4, time_limit_s=5.0))
    b = plan(problem, PlanOptions(seed=4, time_limit_s=5.0))
    assert a.placed == b.placed


def test_rect_plans_report_the_brim_and_the_handle_the_arm_gives() -> None:
    problem = dataset_problem(1)
    result = plan(problem, PlanOptions())
    index = {m.id: i for i, m in enumerate(problem.mugs)}
    for p in result.placed:
        assert p.brim_mm == problem.brim_centre_on_tray(p.type, p.x_mm, p.y_mm)
        wx, wy = problem.to_world_mm(*p.brim_mm)
        assert p.handle_yaw_rad == pytest.approx(math.atan2(wy, wx))  # counter handles face away from the arm
        assert problem.relative_yaw(index[p.id]) == 0.0


def test_the_handle_turns_with_the_pick_bearing_less_the_counter_yaw() -> None:
    # A mug at bearing 90 deg with its handle along +x: 90 deg added to the slot's bearing (flip mirrors).
    problem = replace(dataset_problem(1), mugs=(CounterMug("m1", "big", 0.0, 500.0, 0.0),))
    assert problem.relative_yaw(0) == pytest.approx(math.pi / 2)
    ox, oy = problem.tray_origin_mm
    assert problem.handle_yaw_on_tray(100.0 - ox, 100.0 - oy, math.pi / 2) == pytest.approx(
        math.pi / 4 + math.pi / 2
    )


def test_the_outline_area_is_the_disc_plus_the_handle_beyond_it() -> None:
    o = MugOutline.of(TYPES["big"])
    assert (o.radius, o.handle_from, o.handle_to, o.half_thickness) == (45.5, 45.5, 69.5, 5.0)
    assert o.extent == pytest.approx(74.5)  # the mug's width less its radius
    disc_and_bar = math.pi * 45.5**2 + 10 * 24 + math.pi * 25  # the whole capsule beside the disc
    assert math.pi * 45.5**2 < o.area() < disc_and_bar
    grown = o.area(5.0)
    shapely_area = (
        Point(0, 0)
        .buffer(50.5, quad_segs=256)
        .union(LineString([(45.5, 0), (69.5, 0)]).buffer(10, quad_segs=256))
    )
    assert grown == pytest.approx(shapely_area.area, rel=1e-4)


def test_a_problem_file_names_a_bad_footprint_and_its_handle_yaws() -> None:
    doc: dict[str, object] = {"tray": {"size_mm": [332, 374]}, "mugs": [], "footprint": "round"}
    with pytest.raises(InvalidProblem, match=r"^footprint: 'round' is not one of rect, mug$"):
        Problem.from_json(doc)
    doc["footprint"] = "mug"
    doc["mugs"] = [{"id": "m1", "type": "big", "x_mm": 0, "y_mm": 400, "handle_yaw_rad": "left"}]
    with pytest.raises(InvalidProblem, match=r"^mugs\[0\].handle_yaw_rad: expected a finite number, got '"):
        Problem.from_json(doc)
    doc["mugs"] = [{"id": "m1", "type": "big", "x_mm": 0, "y_mm": 400, "handle_yaw_rad": 1.5}]
    problem = Problem.from_json(doc)
    assert problem.footprint_kind == "mug"
    assert problem.mugs[0].handle_yaw_rad == 1.5
    assert Problem.from_json(problem.to_json()) == problem


def test_mug_footprints_refuse_rotation_and_nested_mugs_already_on_the_tray() -> None:
    base = replace(dataset_problem(1), footprint_kind="mug")
    with pytest.raises(InvalidProblem, match=r"^allow_rotation: mug-shaped footprints turn each handle"):
        replace(base, allow_rotation=True)
    first = TrayMug("p1", "small", 0, 0, handle_yaw_rad=0.0)
    # A second small mug whose brim comes 5 mm from the first one's handle tip.
    with pytest.raises(
        InvalidProblem, match=r"^placed\[1\]: closer than 10 mm to placed\[0\] \(mug outlines\)$"
    ):
        replace(base, placed=(first, TrayMug("p2", "small", 63 + 5 + 5, 0)))
    with pytest.raises(
        InvalidProblem, match=r"^placed\[0\]: brim centre \(42, 42\) mm: the mug and its handle"
    ):
        replace(base, placed=(TrayMug("p1", "small", 0, 0, handle_yaw_rad=math.pi),))


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 7).flatmap(
        lambda n: st.lists(
            st.lists(st.integers(0, 50).map(float), min_size=n, max_size=n), min_size=1, max_size=7
        )
    )
)
def test_the_assignment_costs_what_the_best_of_all_matchings_costs(cost: list[list[float]]) -> None:
    rows, cols = len(cost), len(cost[0])
    pairs = least_cost_assignment(cost)
    assert len(pairs) == min(rows, cols)
    assert len({r for r, _ in pairs}) == len({c for _, c in pairs}) == len(pairs)
    if rows <= cols:
        best = min(
            sum(cost[r][c] for r, c in enumerate(p)) for p in itertools.permutations(range(cols), rows)
        )
    else:
        best = min(
            sum(cost[r][c] for c, r in enumerate(p)) for p in itertools.permutations(range(rows), cols)
        )
    assert sum(cost[r][c] for r, c in pairs) == pytest.approx(best)


@pytest.mark.slow
def test_the_planned_handle_yaw_is_the_one_the_motion_planner_predicts() -> None:
    from daemon.config import load_config
    from description.thesis import MUG_TYPES
    from planning.arm import ArmModel
    from planning.arm.grasp import handle_facing_away_rad
    from planning.interfaces import MugPose
    from planning.motion import CyclePlanner

    cell = load_config().cell
    problem = replace(dataset_problem(3, tray_origin_m=cell.tray.origin_m), footprint_kind="mug")
    result = plan(problem, PlanOptions())
    planner = CyclePlanner(ArmModel.load(), cell, MUG_TYPES)
    slots = {s.mug_id: s for s in result.slots(problem)}
    counter = {m.id: m for m in problem.mugs}
    checked = 0
    for p in result.placed[:: max(1, len(result.placed) // 4)]:
        m = counter[p.id]
        x, y = m.x_mm / 1000.0, m.y_mm / 1000.0
        mug = MugPose(m.id, m.type, x, y, handle_yaw_rad=handle_facing_away_rad(x, y))
        cycle = planner.plan_cycle((0.0, -1.2, 1.7, -2.0, -math.pi / 2), mug, slots[p.id], [])
        assert cycle.handle_yaw_rad is not None
        assert p.handle_yaw_rad is not None
        assert abs(math.remainder(cycle.handle_yaw_rad - p.handle_yaw_rad, math.tau)) < math.radians(2)
        checked += 1
    assert checked >= 4


def test_no_counter_mug_to_place_is_an_empty_plan() -> None:
    # Every counter mug out of reach (or placed): the mug-shaped planner has nothing to pack. Its list of
    # seeded shuffles once never ended for an empty class sequence.
    problem = replace(dataset_problem(1), mugs=(), footprint_kind="mug")
    result = plan(problem, PlanOptions())
    assert (result.n, result.placed, result.unplaced) == (0, (), ())
