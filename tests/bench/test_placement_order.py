"""``dishbot bench placement --layouts N``: its random counter layouts keep the mugs apart as the module
says and repeat with their seed, and its rows do not depend on how many worker processes check them."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bench.placement_order import order_table, random_layout
from cli.main import main
from daemon.config import load_config
from planning.placement import Problem
from planning.placement.datasets import cell_dataset_problem


def _base(n: int) -> Problem:
    return dataclasses.replace(cell_dataset_problem(load_config().cell, n), footprint_kind="mug")


def _handle_gap(problem: Problem, a: tuple[float, float, str], b: tuple[float, float]) -> float:
    """Distance from point ``b`` to ``a``'s handle (from its brim, pointing away from the arm base)."""
    t = problem.mug_types[a[2]]
    r = t.diameter_mm / 2.0
    bx, by = problem.arm_base_mm
    yaw = math.atan2(a[1] - by, a[0] - bx)
    ux, uy = math.cos(yaw), math.sin(yaw)
    p0 = (a[0] + r * ux, a[1] + r * uy)
    s = max(0.0, min(t.width_mm - t.diameter_mm, (b[0] - p0[0]) * ux + (b[1] - p0[1]) * uy))
    return math.hypot(b[0] - (p0[0] + s * ux), b[1] - (p0[1] + s * uy))


@pytest.mark.parametrize("n", [1, 4])
def test_a_random_layout_keeps_brims_and_handles_apart_within_the_counters_box(n: int) -> None:
    base = _base(n)
    layout = random_layout(base, np.random.default_rng([3, n]))
    assert [m.id for m in layout.mugs] == [m.id for m in base.mugs]
    assert [m.type for m in layout.mugs] == [m.type for m in base.mugs]
    xs, ys = [m.x_mm for m in base.mugs], [m.y_mm for m in base.mugs]
    mugs = [(m.x_mm, m.y_mm, m.type) for m in layout.mugs]
    for x, y, _ in mugs:
        assert min(xs) <= x <= max(xs)
        assert min(ys) <= y <= max(ys)
    radius = {t: v.diameter_mm / 2.0 for t, v in base.mug_types.items()}
    for i, a in enumerate(mugs):
        for b in mugs[i + 1 :]:
            # 0.1 mm: the layout rounds its centres to a tenth of a millimetre
            assert math.hypot(a[0] - b[0], a[1] - b[1]) >= radius[a[2]] + radius[b[2]] + 20.0 - 0.15
            assert _handle_gap(base, a, b[:2]) >= radius[b[2]] + 10.0 - 0.15
            assert _handle_gap(base, b, a[:2]) >= radius[a[2]] + 10.0 - 0.15
    # The layouts are spread: not the counter's own positions, and another seed gives others.
    assert [(m.x_mm, m.y_mm) for m in layout.mugs] != [(m.x_mm, m.y_mm) for m in base.mugs]
    again = random_layout(base, np.random.default_rng([3, n]))
    other = random_layout(base, np.random.default_rng([4, n]))
    assert again == layout
    assert other != layout


@pytest.mark.slow
@pytest.mark.timeout(900)  # a cap for a loaded machine (three checked layouts), not a speed claim
def test_the_order_rows_do_not_depend_on_the_worker_processes() -> None:
    def rows(jobs: int) -> list[list[object]]:
        # Dataset 6: the full-size tray's counter, most of it out of reach, the cheapest to check.
        _, table, extra = order_table([6], 1, 0, lambda _: None, jobs=jobs, unchecked=False)
        assert extra["order_collisions (checked), target 0"] == 0
        assert extra["planned but not placed (checked), target 0"] == 0
        return [r[:-1] for r in table]  # all but the CPU time

    one = rows(1)
    assert one == rows(2)
    (row,) = one
    assert row[:3] == [6, 1, 30]
    assert row[4] == row[5]  # planned == placed
    assert row[8:] == ["-", "-", "-"]  # no baseline asked for


def test_the_order_bench_refuses_a_bad_jobs_count(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "placement", "--layouts", "1", "--jobs", "0"]) == 2
    assert capsys.readouterr().err == (
        "dishbot bench: error: --jobs: expected a whole number, at least 1, got '0'\n"
    )
