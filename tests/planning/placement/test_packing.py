"""The fast packer against the literal occupancy-matrix oracle, and the fill orders' meaning."""

from __future__ import annotations

import itertools
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planning.placement import CounterMug, MugType, Problem, TrayMug
from planning.placement.heuristics import Heuristic
from planning.placement.oracle import GridPacker
from planning.placement.order import blocking_violations, execution_order
from planning.placement.packing import Packer


@st.composite
def problems(draw: st.DrawFn) -> tuple[Problem, list[int]]:
    """Small random trays (every footprint fits), 1-3 mug types, up to 14 mugs, up to 2 on the tray."""
    tray = (draw(st.integers(80, 160)), draw(st.integers(80, 160)))
    kinds = draw(st.integers(1, 3))
    types = {}
    for k in range(kinds):
        d = draw(st.integers(5, 45))
        types[f"t{k}"] = MugType(f"t{k}", d, d + draw(st.integers(0, 25)), 50, 0.1)
    tolerance = draw(st.integers(0, 6))
    kind = st.integers(0, kinds - 1).map(lambda k: f"t{k}")
    mugs = tuple(
        CounterMug(f"m{i}", draw(kind), float(i * 10), 300.0) for i in range(draw(st.integers(1, 14)))
    )
    empty = Problem(tray, (0.0, 0.0), (), types, tolerance_mm=tolerance)
    rects: list[tuple[int, int, int, int]] = []
    placed = []
    for j in range(draw(st.integers(0, 2))):
        t = draw(kind)
        fx, fy = empty.footprint(t)
        x, y = draw(st.integers(0, tray[0] - fx)), draw(st.integers(0, tray[1] - fy))
        if all(x >= x1 or x0 >= x + fx or y >= y1 or y0 >= y + fy for x0, y0, x1, y1 in rects):
            rects.append((x, y, x + fx, y + fy))
            placed.append(TrayMug(f"p{j}", t, x, y))
    problem = Problem(tray, (0.0, 0.0), mugs, types, tuple(placed), tolerance, draw(st.booleans()))
    return problem, list(draw(st.permutations(range(len(mugs)))))


@settings(max_examples=150, deadline=None)
@given(problems(), st.sampled_from(list(Heuristic)), st.randoms(use_true_random=False))
@pytest.mark.slow
def test_fast_packer_places_every_mug_where_the_occupancy_matrix_does(
    case: tuple[Problem, list[int]], heuristic: Heuristic, rng: random.Random
) -> None:
    problem, order = case
    packer = Packer(problem, heuristic)
    # Several orders through one packer, so cached prefixes and their first-fit hints are reused.
    for _ in range(3):
        assert packer.pack(order) == GridPacker(problem, heuristic).pack(order)
        rng.shuffle(order)


def _single(problem_tray: tuple[int, int], heuristic: Heuristic) -> tuple[int, int]:
    types = {"cup": MugType("cup", 20, 30, 50, 0.1)}
    p = Problem(problem_tray, (0.0, 0.0), (CounterMug("a", "cup", 0.0, 0.0),), types, tolerance_mm=0)
    spot = Packer(p, heuristic).pack([0]).spots[0]
    assert spot is not None
    return spot[0], spot[1]


def test_fill_orders_start_from_their_named_corner() -> None:
    # 100 x 80 tray, 30 x 20 footprint: bottom = x 0, top = x 70; right = y 0, left = y 60.
    corners = {h: _single((100, 80), h) for h in Heuristic}
    assert corners[Heuristic.BLF] == corners[Heuristic.LBF] == (0, 60)
    assert corners[Heuristic.TLF] == corners[Heuristic.LTF] == (70, 60)
    assert corners[Heuristic.BRF] == corners[Heuristic.RBF] == (0, 0)
    assert corners[Heuristic.TRF] == corners[Heuristic.RTF] == (70, 0)


def test_ltf_fills_a_column_before_moving_right_and_tlf_a_row_before_moving_down() -> None:
    types = {"cup": MugType("cup", 20, 30, 50, 0.1)}
    mugs = tuple(CounterMug(f"m{i}", "cup", 0.0, 0.0) for i in range(3))
    p = Problem((100, 80), (0.0, 0.0), mugs, types, tolerance_mm=0)
    ltf = Packer(p, Heuristic.LTF).pack([0, 1, 2]).spots
    tlf = Packer(p, Heuristic.TLF).pack([0, 1, 2]).spots
    assert [s[:2] for s in ltf if s] == [(70, 60), (40, 60), (10, 60)]
    assert [s[:2] for s in tlf if s] == [(70, 60), (70, 40), (70, 20)]


def test_mug_that_does_not_fit_is_skipped_and_a_smaller_one_still_goes_in() -> None:
    types = {"big": MugType("big", 50, 60, 50, 0.2), "small": MugType("small", 20, 20, 50, 0.1)}
    mugs = (CounterMug("b1", "big", 0, 0), CounterMug("b2", "big", 0, 0), CounterMug("s1", "small", 0, 0))
    p = Problem((70, 70), (0.0, 0.0), mugs, types, tolerance_mm=0)
    packing = Packer(p, Heuristic.BLF).pack([0, 1, 2])
    assert packing.placed == (0, 2)
    assert packing.unplaced == (1,)


def test_execution_order_never_reaches_over_a_placed_mug() -> None:
    grid = [(k, x, y, 30, 20) for k, (x, y) in enumerate(itertools.product((0, 30, 60), (0, 25, 50)))]
    order = execution_order(grid)
    by_id = {f[0]: f for f in grid}
    assert blocking_violations([by_id[m] for m in order]) == []
    assert blocking_violations(grid) != []  # counter order (bottom row first) would collide
