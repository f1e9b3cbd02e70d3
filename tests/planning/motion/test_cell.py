"""The start-up reachability check of a cell layout (``planning.motion.check_reachable``)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from daemon.config import load_config
from description.cell import CellLayout
from description.thesis import BIG_MUG
from planning.arm import ArmModel
from planning.motion import carry_height_m, check_reachable
from planning.motion.cell import tray_axis_area


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _cell(
    counter_region_m: tuple[float, float, float, float], tray_origin_m: tuple[float, float] = (0.34, -0.187)
) -> CellLayout:
    """The default cell with another counter region and tray corner."""
    default = load_config().cell
    return replace(
        default, counter_region_m=counter_region_m, tray=replace(default.tray, origin_m=tray_origin_m)
    )


def test_default_cell_is_reachable_everywhere(arm: ArmModel) -> None:
    assert check_reachable(load_config().cell, arm) == []


def test_a_tray_next_to_the_base_is_refused_with_its_near_points(arm: ArmModel) -> None:
    problems = check_reachable(_cell((-0.45, 0.37, 0.45, 0.575), (0.10, -0.187)), arm)
    assert problems
    assert all(p.startswith("tray point (0.1") for p in problems)
    assert "side-upside-down grasp at z=0.060 m: no solution within the joint limits" in problems[0]


def test_a_counter_region_beyond_reach_names_the_far_corners(arm: ArmModel) -> None:
    problems = check_reachable(_cell((-0.30, 0.40, 0.25, 0.90)), arm)
    # Mug axes stay a small mug's brim radius (37 mm) inside the region.
    assert [p.split(" m,")[0] for p in problems] == [
        "counter point (0.213, 0.863)",
        "counter point (-0.263, 0.863)",
    ]
    assert "out of reach for a side grasp: the wrist would be" in problems[0]


def test_a_counter_region_reaching_in_to_the_base_names_its_nearest_point(arm: ArmModel) -> None:
    problems = check_reachable(_cell((-0.30, 0.25, 0.25, 0.55)), arm)
    assert [p.split(" m,")[0] for p in problems] == [
        "counter point (0.213, 0.287)",
        "counter point (0.000, 0.287)",
    ]


def test_the_tray_check_keeps_the_cells_tolerance_around_each_footprint(arm: ArmModel) -> None:

    cell = load_config().cell
    loose = replace(cell, tolerance_mm=30)
    tight, wide = tray_axis_area(cell, BIG_MUG), tray_axis_area(loose, BIG_MUG)
    # 20 mm more tolerance: each side of the axis area moves in by 10 mm.
    assert [round(w - t, 4) for w, t in zip(wide, tight, strict=True)] == [0.01, 0.01, -0.01, -0.01]


def test_carry_height_keeps_three_centimetres_under_the_held_mug() -> None:
    # 106 mm mug: the thesis's 7 cm above it would leave the held mug's bottom 1 cm above; raise to 3 cm
    # (plus a 5 mm margin for the IK residual).
    assert carry_height_m(0.106) == pytest.approx(0.106 + 0.03 + 0.06 + 0.005)
