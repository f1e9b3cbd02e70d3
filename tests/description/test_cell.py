"""The one cell layout (``description.cell``): validated once, naming the config field; its tray."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from description.camera import CameraSpec
from description.cell import CellLayout, Tray
from description.errors import InvalidCell

CAMERA = CameraSpec(640, 480, 72.0, (0.115, 1.325, 0.80), -math.pi / 2, math.radians(55.0))
TRAY = Tray(origin_m=(0.34, -0.187), size_mm=(332, 374))
CELL = CellLayout((-0.45, 0.37, 0.45, 0.575), (0.30, -0.40), 0.08, TRAY, CAMERA)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"counter_region_m": (0.30, 0.30, 0.25, 0.62)},
            "cell.counter_region_m: [0.3, 0.3, 0.25, 0.62] is not [x_min, y_min, x_max, y_max] "
            "with min < max",
        ),
        ({"flip_area_radius_m": 0.0}, "cell.flip_area_radius_m: 0.0 must be > 0"),
        ({"flip_area_center_m": (math.nan, 0.0)}, "cell: every coordinate must be a finite number of metres"),
        ({"table_height_above_floor_m": -1.0}, "cell.table_height_above_floor_m: -1.0 must be > 0"),
        ({"tolerance_mm": -1}, "planner.tolerance_mm: -1 must be >= 0"),
    ],
)
def test_a_malformed_cell_is_refused_naming_the_config_field(change: dict[str, object], message: str) -> None:
    with pytest.raises(InvalidCell) as info:
        replace(CELL, **change)  # type: ignore[arg-type]
    assert str(info.value) == message


@pytest.mark.parametrize(
    ("tray", "message"),
    [
        ({"size_mm": (332, 0)}, "cell.tray_size_mm: [332, 0] must be two positive lengths"),
        (
            {"origin_m": (math.inf, 0.0)},
            "cell.tray_origin_m: [inf, 0.0] must be two finite numbers of metres",
        ),
        ({"wall_thickness_m": -0.001}, "tray wall_thickness_m: -0.001 must be a length >= 0"),
    ],
)
def test_a_malformed_tray_is_refused_naming_the_field(tray: dict[str, object], message: str) -> None:
    with pytest.raises(InvalidCell) as info:
        replace(TRAY, **tray)  # type: ignore[arg-type]
    assert str(info.value) == message


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"width": 8}, "camera.width, camera.height: 8x480 pixels; use at least 16x16"),
        ({"fovy_deg": 150.0}, "camera.fovy_deg: 150 is out of range; allowed [10, 120]"),
        ({"pitch_rad": -0.1}, "camera.pitch_rad: -0.1 does not look down; allowed (0, 1.5708)"),
    ],
)
def test_a_camera_that_cannot_see_the_cell_is_refused_naming_the_field(
    change: dict[str, object], message: str
) -> None:
    with pytest.raises(InvalidCell) as info:
        replace(CAMERA, **change)  # type: ignore[arg-type]
    assert str(info.value) == message


def test_the_tray_has_its_inner_rectangle_its_walls_outside_it_and_its_base_under_the_mugs() -> None:
    assert TRAY.region_m == pytest.approx((0.34, -0.187, 0.672, 0.187))
    assert TRAY.outer_region_m == pytest.approx((0.332, -0.195, 0.68, 0.195))  # 8 mm walls
    assert TRAY.contains(0.5, 0.0)
    assert not TRAY.contains(0.335, 0.0)  # on the wall, not inside
    assert TRAY.to_world(100.0, 50.0) == pytest.approx((0.44, -0.137))
    assert CELL.mug_base_z_m(0.5, 0.0) == TRAY.base_m
    assert CELL.mug_base_z_m(0.0, 0.45) == 0.0


def test_the_table_reaches_past_the_counter_tray_walls_flip_area_and_arm_base() -> None:
    x0, y0, x1, y1 = CELL.table_region_m
    assert (x0, y0, x1, y1) == pytest.approx((-0.45 - 0.05, -0.48 - 0.05, 0.68 + 0.05, 0.575 + 0.05))


def test_another_tray_changes_only_the_tray() -> None:
    full = Tray(origin_m=(0.25, -0.26), size_mm=(475, 520))
    swapped = CELL.with_tray(full)
    assert swapped.tray == full
    assert replace(swapped, tray=TRAY) == CELL
