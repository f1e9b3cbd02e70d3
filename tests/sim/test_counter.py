"""The simulated counter set-up (``sim.counter``): a dataset's mugs where its placement problem puts them,
the tray they go to, and the one refusal of a tray the cell does not have."""

from __future__ import annotations

import math

import pytest

from daemon.config import load_config
from description import thesis
from description.cell import Tray
from description.thesis import MUG_TYPES
from planning.placement import cell_dataset_problem
from planning.placement.datasets import FULL_TRAY_ORIGIN_M
from sim.counter import counter_mugs, dataset_counter, listed_counter, require_cell_tray

FULL_TRAY_MESSAGE = (
    "dataset {n} needs the full-size tray (475 x 520 mm), which the MuJoCo cell does not have (its tray is "
    "the configured 332 x 374 mm one); use dataset 1, 2, 3 or the kinematic cell"
)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_a_robot_tray_dataset_stands_where_its_problem_puts_it_and_fills_the_cells_tray(n: int) -> None:
    cell = load_config().cell
    counter = dataset_counter(n, cell, MUG_TYPES)
    problem = cell_dataset_problem(cell, n)
    assert counter.tray is cell.tray
    assert counter.dataset == n
    assert [(m.mug_id, m.spec.name, m.x_m, m.y_m) for m in counter.mugs] == [
        (m.id, m.type, m.x_mm / 1000.0, m.y_mm / 1000.0) for m in problem.mugs
    ]
    for m in counter.mugs:
        assert not m.upside_down
        assert m.yaw_rad == pytest.approx(math.atan2(m.y_m, m.x_m))  # handle away from the arm
        x0, y0, x1, y1 = cell.counter_region_m
        assert x0 <= m.x_m <= x1
        assert y0 <= m.y_m <= y1
    require_cell_tray(counter, cell)  # fits: nothing raised


@pytest.mark.parametrize("n", [4, 5, 6])
def test_a_full_size_tray_dataset_brings_its_own_tray_and_is_refused_where_the_tray_is_built_in(
    n: int,
) -> None:
    cell = load_config().cell
    counter = dataset_counter(n, cell, MUG_TYPES)
    assert counter.tray == Tray(FULL_TRAY_ORIGIN_M, thesis.FULL_TRAY_MM)
    assert len(counter.mugs) == 30
    with pytest.raises(ValueError, match=r"^dataset \d needs the full-size tray") as info:
        require_cell_tray(counter, cell)
    assert str(info.value) == FULL_TRAY_MESSAGE.format(n=n)


def test_listed_mugs_go_to_the_cells_tray_with_their_handles_away_from_the_arm() -> None:
    cell = load_config().cell
    counter = listed_counter([("a", "big", 0.1, 0.45), ("b", "small", -0.2, 0.4)], cell, MUG_TYPES)
    assert (counter.tray, counter.dataset) == (cell.tray, None)
    assert [(m.mug_id, m.spec, round(m.yaw_rad, 4)) for m in counter.mugs] == [
        ("a", thesis.BIG_MUG, round(math.atan2(0.45, 0.1), 4)),
        ("b", thesis.SMALL_MUG, round(math.atan2(0.4, -0.2), 4)),
    ]


def test_unknown_mug_type_is_refused_with_the_catalogue_named() -> None:
    with pytest.raises(ValueError, match=r"^mug types tall are not in the catalogue \(big, small\)$"):
        counter_mugs([("a", "tall", 0.0, 0.4)], MUG_TYPES)


def test_a_dataset_needs_its_mug_types_in_the_catalogue() -> None:
    with pytest.raises(ValueError, match=r"^mug types small are not in the catalogue \(big\)$"):
        dataset_counter(1, load_config().cell, {"big": thesis.BIG_MUG})
