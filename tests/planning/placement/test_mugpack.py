"""The mug packer's search: each mug goes to the first corner of its scan where it fits, exactly as a packer
that clears every class's whole grid after every placement would put it (the packer itself clears only
brims at once and tests handles lazily, on the corners a scan reaches)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from planning.placement import PlanOptions, dataset_problem, mugpack, plan
from planning.placement.mugpack import BEARING_MM, SCANS, MugPacker, Scan, Spot, _axis, _scan_orders
from planning.placement.mugshaped import PACKS_BASE, area_bound
from planning.placement.problem import Problem
from planning.placement.shapes import (
    NEAR_SLACK_MM,
    Bodies,
    MugOutline,
    Row,
    clear_of,
    clear_of_all,
    clear_of_each,
    near_rows,
    row,
)
from tests.planning.placement.test_mug_footprint import counter_mugs, mug_problem


def eager_pack(packer: MugPacker, sequence: list[int], scan: Scan) -> list[Spot]:
    """The reference: after every placement, every corner of every class is tested against the new mug
    (``clear_of``, one placed mug at a time); each mug takes the free corner that comes first in ``scan``."""
    p = packer.problem
    free = [c.free.copy() for c in packer.classes]
    spots: list[Spot] = []
    for k in sequence:
        c = packer.classes[k]
        side = p.mug_types[c.type].diameter_mm + p.tolerance_mm
        order = _scan_orders(
            p.tray_size_mm[0] - side,
            p.tray_size_mm[1] - side,
            2,
            side / 2.0,
            p.tray_origin_mm,
            p.arm_base_mm,
        )[scan]
        flat = free[k].reshape(-1)
        taken = np.flatnonzero(flat[order])
        if not taken.size:
            continue
        cell = int(order[taken[0]])
        i, j = divmod(cell, len(c.ys))
        spots.append((k, int(c.xs[i]), int(c.ys[j])))
        one = Bodies(*(np.array([getattr(c.bodies, f)[i, j]]) for f in Bodies.__dataclass_fields__))
        for q, other in enumerate(packer.classes):
            if not free[q].size:
                continue
            every = Bodies(*(getattr(other.bodies, f).reshape(-1) for f in Bodies.__dataclass_fields__))
            free[q] &= clear_of(every, one, 0, packer.clearance).reshape(free[q].shape)
    return spots


@settings(max_examples=30, deadline=None)
@given(
    size=st.tuples(st.integers(140, 300), st.integers(140, 300)),
    tolerance=st.integers(0, 20),
    mugs=counter_mugs,
    sequence_seed=st.integers(0, 1000),
    scan=st.sampled_from(SCANS),
)
def test_each_mug_goes_to_the_first_corner_of_its_scan_where_it_fits(
    size: tuple[int, int],
    tolerance: int,
    mugs: list[tuple[str, float, float, float | None]],
    sequence_seed: int,
    scan: Scan,
) -> None:
    packer = MugPacker(mug_problem(size, tolerance, mugs))
    sequence = sorted(packer.class_of, key=lambda k: (k * 7919 + sequence_seed) % 13)
    assert packer.pack(sequence, scan) == eager_pack(packer, sequence, scan)


@settings(max_examples=20, deadline=None)
@given(
    size=st.tuples(st.integers(140, 300), st.integers(140, 300)),
    mugs=counter_mugs,
    sequence_seed=st.integers(0, 1000),
    scan=st.sampled_from(SCANS),
    tries=st.integers(1, 3),
)
def test_past_its_first_tries_the_search_tests_in_batches_with_the_same_result(
    size: tuple[int, int],
    mugs: list[tuple[str, float, float, float | None]],
    sequence_seed: int,
    scan: Scan,
    tries: int,
) -> None:
    """With only ``tries`` corners tested one at a time, the rest go to the numpy batches (``clear_of_all``;
    the datasets' searches never get that far): each mug still takes the reference's corner."""
    packer = MugPacker(mug_problem(size, 10, mugs))
    sequence = sorted(packer.class_of, key=lambda k: (k * 7919 + sequence_seed) % 13)
    kept = mugpack.SCALAR_TRIES
    mugpack.SCALAR_TRIES = tries
    try:
        assert packer.pack(sequence, scan) == eager_pack(packer, sequence, scan)
    finally:
        mugpack.SCALAR_TRIES = kept


@settings(max_examples=15, deadline=None)
@given(
    size=st.tuples(st.integers(180, 300), st.integers(180, 300)),
    mugs=counter_mugs,
    packings=st.lists(st.tuples(st.integers(0, 1000), st.sampled_from(SCANS)), min_size=2, max_size=6),
)
def test_what_one_packing_finds_too_close_leaves_the_next_ones_unchanged(
    size: tuple[int, int],
    mugs: list[tuple[str, float, float, float | None]],
    packings: list[tuple[int, Scan]],
) -> None:
    """One packer packs several sequences under several scans (as the search does), each later packing
    starting from what the earlier ones found too close to the spots they used: each is still the
    reference's."""
    packer = MugPacker(mug_problem(size, 10, mugs))
    for seed, scan in packings + packings:  # and again: the same spots, every refusal known
        sequence = sorted(packer.class_of, key=lambda k: (k * 7919 + seed) % 13)
        assert packer.pack(sequence, scan) == eager_pack(packer, sequence, scan)


@settings(max_examples=40, deadline=None)
@given(
    mine=st.lists(st.tuples(st.floats(0, 300), st.floats(0, 300), st.floats(-4, 4)), min_size=1, max_size=20),
    others=st.lists(
        st.tuples(st.floats(0, 300), st.floats(0, 300), st.floats(-4, 4)), min_size=1, max_size=6
    ),
    clearance=st.floats(0, 20),
)
def test_clear_of_all_is_clear_of_every_other_mug(
    mine: list[tuple[float, float, float]], others: list[tuple[float, float, float]], clearance: float
) -> None:
    outline = mug_problem((300, 300), 10, [("big", 0.0, 400.0, None)]).mug_types["big"]

    def bodies(rows: list[tuple[float, float, float]]) -> Bodies:
        a = np.array(rows, dtype=float)
        return Bodies.build(MugOutline.of(outline), a[:, 0], a[:, 1], a[:, 2])

    a, b = bodies(mine), bodies(others)
    expected = np.ones(len(mine), bool)
    for k in range(len(others)):
        expected &= clear_of(a, b, k, clearance)
    assert clear_of_all(a, b, clearance).tolist() == expected.tolist()


mug_rows = st.lists(
    st.tuples(
        st.floats(0, 300),
        st.floats(0, 300),
        st.floats(-4, 4),
        st.sampled_from(["big", "small"]),
        st.floats(0, 0.2),
    ),
    min_size=1,
    max_size=12,
)


@settings(max_examples=200, deadline=None)
@given(mine=mug_rows, others=mug_rows, clearance=st.floats(0, 20), grid=st.booleans())
def test_the_scalar_clearance_agrees_with_the_vectorised_one(
    mine: list[tuple[float, float, float, str, float]],
    others: list[tuple[float, float, float, str, float]],
    clearance: float,
    grid: bool,
) -> None:
    """``clear_of_each`` (one mug, plain floats: the packer's first tries) says what ``clear_of_all``
    (numpy, the batches) says, for mugs of both types with handles thickened as a class's are; ``grid``
    snaps the brims to whole millimetres and the clearance to a whole number, where outlines touch exactly
    at the clearance (the packer's grid)."""
    types = mug_problem((300, 300), 10, [("big", 0.0, 400.0, None)]).mug_types

    def bodies(rows: list[tuple[float, float, float, str, float]]) -> Bodies:
        parts = []
        for x, y, yaw, kind, thicker in rows:
            o = MugOutline.of(types[kind])
            o = replace(o, half_thickness=o.half_thickness + thicker * o.handle_to)
            if grid:
                x, y = float(round(x)), float(round(y))
            parts.append(Bodies.build(o, np.array([x]), np.array([y]), np.array([yaw])))
        return Bodies(*(np.concatenate([getattr(b, f) for b in parts]) for f in Bodies.__dataclass_fields__))

    gap = float(round(clearance)) if grid else clearance
    a, b = bodies(mine), bodies(others)
    vectorised = clear_of_all(a, b, gap).tolist()
    stacked = np.stack([getattr(b, f) for f in Bodies.__dataclass_fields__], axis=1)
    rows_b = [row(r) for r in stacked.tolist()]
    mine_rows = np.stack([getattr(a, f) for f in Bodies.__dataclass_fields__], axis=1).tolist()
    assert [clear_of_each(row(r), rows_b, gap) for r in mine_rows] == vectorised


@settings(max_examples=100, deadline=None)
@given(
    mine=mug_rows,
    others=mug_rows,
    clearance=st.floats(0, 20),
    at=st.tuples(st.floats(0, 300), st.floats(0, 300)),
)
def test_the_mugs_near_a_point_are_all_a_mug_near_it_can_touch(
    mine: list[tuple[float, float, float, str, float]],
    others: list[tuple[float, float, float, str, float]],
    clearance: float,
    at: tuple[float, float],
) -> None:
    """A mug whose axis lies within ``NEAR_SLACK_MM`` of a point is clear of every mug that ``near_rows``
    leaves out there (the packer tests the corners of a scan against the first one's near mugs)."""
    types = mug_problem((300, 300), 10, [("big", 0.0, 400.0, None)]).mug_types

    def rows(items: list[tuple[float, float, float, str, float]]) -> list[Row]:
        out = []
        for x, y, yaw, kind, thicker in items:
            o = MugOutline.of(types[kind])
            o = replace(o, half_thickness=o.half_thickness + thicker * o.handle_to)
            b = Bodies.build(o, np.array([x]), np.array([y]), np.array([yaw]))
            out.append(row([float(getattr(b, f)[0]) for f in Bodies.__dataclass_fields__]))
        return out

    everyone = rows(others)
    for m in rows(mine):
        # moved to within the slack of the point, in the direction it lies
        dx, dy = m[0] - at[0], m[1] - at[1]
        scale = min(1.0, NEAR_SLACK_MM / max(float(np.hypot(dx, dy)), 1e-9))
        x, y, yaw = at[0] + dx * scale, at[1] + dy * scale, float(np.arctan2(m[4] - m[1], m[3] - m[0]))
        o = MugOutline(m[2], float(np.hypot(m[3] - m[0], m[4] - m[1])), 0.0, m[7])
        o = replace(o, handle_to=o.handle_from + 2 * m[14])
        b = Bodies.build(o, np.array([x]), np.array([y]), np.array([yaw]))
        moved = row([float(getattr(b, f)[0]) for f in Bodies.__dataclass_fields__])
        near = near_rows(at[0], at[1], moved[8] + clearance, everyone)
        assert all(clear_of_each(moved, [o], clearance) for o in everyone if o not in near)
        assert clear_of_each(moved, near, clearance) == clear_of_each(moved, everyone, clearance)


def test_the_scalar_clearance_measures_what_shapely_measures() -> None:
    """Two big mugs, one moved along x past the other, handles crossing, touching and apart: clear exactly
    where shapely's distance between the outlines is at least the clearance."""
    from shapely.geometry import LineString, Point

    o = MugOutline.of(mug_problem((300, 300), 10, [("big", 0.0, 400.0, None)]).mug_types["big"])

    def parts(x: float, y: float, yaw: float) -> tuple[Point, LineString]:
        c, s = np.cos(yaw), np.sin(yaw)
        bar = LineString(
            [(x + o.handle_from * c, y + o.handle_from * s), (x + o.handle_to * c, y + o.handle_to * s)]
        )
        return Point(x, y), bar

    fixed = (100.0, 100.0, 0.0)
    p2, b2 = parts(*fixed)
    one = row(
        np.array(
            [
                getattr(Bodies.build(o, *(np.array([v]) for v in fixed)), f)[0]
                for f in Bodies.__dataclass_fields__
            ]
        ).tolist()
    )
    for x in np.arange(100.0, 320.0, 1.5):
        for y, yaw in (
            (160.0, np.pi),
            (100.0 + 2 * o.radius + 2 * o.half_thickness, np.pi / 2),
            (140.0, 3.0),
        ):
            b = Bodies.build(o, np.array([x]), np.array([y]), np.array([yaw]))
            mine = row(np.array([getattr(b, f)[0] for f in Bodies.__dataclass_fields__]).tolist())
            p1, b1 = parts(x, y, yaw)
            gap = min(
                p1.distance(p2) - 2 * o.radius,
                p1.distance(b2) - o.radius - o.half_thickness,
                b1.distance(p2) - o.half_thickness - o.radius,
                b1.distance(b2) - 2 * o.half_thickness,
            )
            if abs(gap - 10.0) > 1e-6:  # exactly at the clearance: either answer is within float rounding
                assert clear_of_each(mine, [one], 10.0) == (gap >= 10.0), (x, y, yaw, gap)


def test_handles_that_cross_far_from_their_ends_are_not_clear() -> None:
    """Two long thin handles crossing at right angles, every end 49 mm or more from the other handle and
    the brims far apart: they touch (shapely: distance 0), so neither test finds them clear."""
    from shapely.geometry import LineString

    o = MugOutline(radius=1.0, handle_from=1.0, handle_to=100.0, half_thickness=0.5)
    a = Bodies.build(o, np.array([0.0]), np.array([0.0]), np.array([0.0]))
    b = Bodies.build(o, np.array([50.0]), np.array([-50.0]), np.array([np.pi / 2]))
    assert LineString([(1, 0), (100, 0)]).distance(LineString([(50, -49), (50, 50)])) == 0.0

    def one(m: Bodies) -> list[float]:
        return [float(getattr(m, f)[0]) for f in Bodies.__dataclass_fields__]

    assert not clear_of_all(a, b, 10.0)[0]
    assert not clear_of_each(row(one(a)), [row(one(b))], 10.0)
    moved = Bodies.build(o, np.array([50.0]), np.array([-150.0]), np.array([np.pi / 2]))  # ends 49 mm short
    assert clear_of_all(a, moved, 10.0)[0]
    assert clear_of_each(row(one(a)), [row(one(moved))], 10.0)


@settings(max_examples=40, deadline=None)
@given(
    limits=st.tuples(st.integers(-2, 60), st.integers(-2, 60)),
    grid_mm=st.integers(1, 5),
    offset=st.sampled_from([30.0, 42.0, 50.5]),
    origin=st.tuples(st.floats(-200, 200), st.floats(-300, 300)),
    base=st.sampled_from([(0.0, 0.0), (25.0, -30.0)]),
)
@example(limits=(40, 40), grid_mm=2, offset=30.0, origin=(-50.0, -50.0), base=(0.0, 0.0))  # ties
def test_every_scan_order_is_its_lexicographic_definition(
    limits: tuple[int, int],
    grid_mm: int,
    offset: float,
    origin: tuple[float, float],
    base: tuple[float, float],
) -> None:
    """``_scan_orders`` (stable sorts over shared secondary orders) gives exactly ``_order``'s lexsorts,
    ties included: a grid of corners on both sides of the arm base, some on its axes."""
    xs, ys = _axis(limits[0], grid_mm), _axis(limits[1], grid_mm)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    cx, cy = np.meshgrid(xs + offset, ys + offset, indexing="ij")
    wx, wy = cx + origin[0] - base[0], cy + origin[1] - base[1]
    polar = (np.hypot(wx, wy), np.arctan2(wy, wx))
    orders = _scan_orders.__wrapped__(limits[0], limits[1], grid_mm, offset, origin, base)
    for scan in SCANS:
        assert orders[scan].tolist() == _order(gx, gy, scan, polar).tolist(), scan


def test_the_search_stops_once_every_counter_mug_is_placed() -> None:
    """A tray with room for every counter mug: the first packing that places them all ends the search
    (the area bound is all of them), with as many mugs as the full search would place."""
    problem: Problem = replace(dataset_problem(1), footprint_kind="mug")
    few = replace(problem, mugs=problem.mugs[:5])
    assert area_bound(few) == 5
    result = plan(few, PlanOptions(method="auto", time_limit_s=1.0))
    assert result.n == 5
    packings = int(result.notes[0].split(" after ")[1].split()[0])
    assert packings < PACKS_BASE


@pytest.mark.parametrize("seed", [0, 1])
def test_a_seed_repeats_the_packers_result(seed: int) -> None:
    problem = replace(dataset_problem(2), footprint_kind="mug")
    options = PlanOptions(method="auto", time_limit_s=1.0, seed=seed)
    first, again = plan(problem, options), plan(problem, options)
    assert [(p.id, p.x_mm, p.y_mm, p.order) for p in first.placed] == [
        (p.id, p.x_mm, p.y_mm, p.order) for p in again.placed
    ]


def _order(
    gx: npt.NDArray[np.int64],
    gy: npt.NDArray[np.int64],
    scan: Scan,
    polar: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
) -> npt.NDArray[np.int64]:
    """The flat corner indices in ``scan``'s order; ``polar``: the brim centre's distance (mm) and bearing
    (rad) from the arm base at each corner: the definition ``mugpack._scan_orders`` computes faster."""
    axis, slant, direction = scan
    if axis in (0, 1):
        primary, secondary = (gx, gy) if axis == 0 else (gy, gx)
        return np.lexsort(((direction * secondary).ravel(), (primary + slant * secondary).ravel()))
    distance, bearing = polar
    if axis == 2:
        keys = (direction * bearing, distance + slant * BEARING_MM * bearing)
    else:
        keys = (distance, direction * BEARING_MM * bearing + slant * distance)
    return np.lexsort((keys[0].ravel(), keys[1].ravel()))
