"""The mug packer's search: each mug goes to the first corner of its scan where it fits, exactly as a packer
that clears every class's whole grid after every placement would put it (the packer itself clears only
brims at once and tests handles lazily, on the corners a scan reaches)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planning.placement import PlanOptions, dataset_problem, plan
from planning.placement.mugpack import SCANS, MugPacker, Scan, Spot, _scan_orders
from planning.placement.mugshaped import PACKS_BASE, area_bound
from planning.placement.problem import Problem
from planning.placement.shapes import Bodies, MugOutline, clear_of, clear_of_all
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
