"""The work cell: counter region, flip area, tray and camera in the world frame, and the mugs set on it.

``CellLayout`` is the one description of the cell. The daemon's config builds it once from ``[cell]`` and
``[camera]`` (``daemon.config``); motion planning checks it against the arm (``planning.motion.cell``),
perception searches its table, the simulated worlds are built from it and the benches measure on it. Its
``Tray`` is a value of its own because the tray is what a job fills: a simulated counter set up with a
full-size-tray dataset swaps it (``CellLayout.with_tray``) and keeps everything else.

The world frame is the daemon's: origin on the arm's shoulder-turn axis at counter height (z = 0 is the
counter top), x forward, y to the robot's left, z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Final

from description.camera import CameraSpec
from description.errors import InvalidCell
from description.thesis import (
    CAMERA_DISTANCE_TO_TABLE_M,
    CAMERA_HEIGHT_M,
    CAMERA_PITCH_RAD,
    TOLERANCE_MM,
    MugSpec,
)

MUG_PREFIX: Final = "mug/"  # every body of a mug is named under it

# How far the table top reaches past everything placed on it.
TABLE_MARGIN_M: Final = 0.05
# The arm's base on the table, a square around the shoulder axis (the table reaches past it).
_ARM_BASE_HALF_M: Final = 0.08


@dataclass(frozen=True, slots=True)
class SceneMug:
    """A mug placed in the scene: its axis at (x_m, y_m) on what it stands on, handle towards ``yaw_rad``."""

    mug_id: str
    spec: MugSpec
    x_m: float
    y_m: float
    yaw_rad: float = 0.0
    upside_down: bool = False

    @property
    def body_name(self) -> str:
        return f"{MUG_PREFIX}{self.mug_id}"


@dataclass(frozen=True, slots=True)
class Tray:
    """The dishwasher tray on the table: its inner rectangle (the corner nearest the arm base, and its extent
    in mm along x and y, as placement plans it), its base and its walls, which stand outside the inner
    rectangle. Base and walls are the simulated tray's (not thesis figures, not in the config); the cycle
    planner keeps the gripper clear of them."""

    origin_m: tuple[float, float]
    size_mm: tuple[int, int]
    base_m: float = 0.006
    wall_height_m: float = 0.025
    wall_thickness_m: float = 0.008

    def __post_init__(self) -> None:
        if len(self.size_mm) != 2 or min(self.size_mm) <= 0:
            raise InvalidCell(f"cell.tray_size_mm: {list(self.size_mm)} must be two positive lengths")
        if len(self.origin_m) != 2 or not all(math.isfinite(v) for v in self.origin_m):
            raise InvalidCell(
                f"cell.tray_origin_m: {list(self.origin_m)} must be two finite numbers of metres"
            )
        for name in ("base_m", "wall_height_m", "wall_thickness_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidCell(f"tray {name}: {value} must be a length >= 0")

    @property
    def region_m(self) -> tuple[float, float, float, float]:
        """The inner rectangle (x_min, y_min, x_max, y_max) mugs stand in."""
        x0, y0 = self.origin_m
        return x0, y0, x0 + self.size_mm[0] / 1000.0, y0 + self.size_mm[1] / 1000.0

    @property
    def outer_region_m(self) -> tuple[float, float, float, float]:
        """The tray with its walls (x_min, y_min, x_max, y_max)."""
        x0, y0, x1, y1 = self.region_m
        w = self.wall_thickness_m
        return x0 - w, y0 - w, x1 + w, y1 + w

    def contains(self, x_m: float, y_m: float) -> bool:
        """Whether a point of the world frame lies over the inner rectangle."""
        x0, y0, x1, y1 = self.region_m
        return x0 <= x_m <= x1 and y0 <= y_m <= y1

    def to_world(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """A point in tray coordinates (mm from the corner nearest the arm) in the world frame (m)."""
        return self.origin_m[0] + x_mm / 1000.0, self.origin_m[1] + y_mm / 1000.0

    def to_tray_mm(self, x_m: float, y_m: float) -> tuple[float, float]:
        """A point of the world frame (m) in tray coordinates (mm from the corner nearest the arm)."""
        return x_m * 1000.0 - self.origin_m[0] * 1000.0, y_m * 1000.0 - self.origin_m[1] * 1000.0


@dataclass(frozen=True, slots=True)
class CellLayout:
    """The cell: counter region (x_min, y_min, x_max, y_max) where mugs wait, flip area (centre, radius)
    where they are turned over, the tray, the depth camera, the table's height above the floor and the
    tolerance between mug footprints on the tray (mm, Table 5.19; the config's ``planner.tolerance_mm``).

    Metres in the world frame; z = 0 is the counter top and the tray stands on it. Construction validates
    it, naming the config field that is wrong (``InvalidCell``)."""

    counter_region_m: tuple[float, float, float, float]
    flip_area_center_m: tuple[float, float]
    flip_area_radius_m: float
    tray: Tray
    camera: CameraSpec
    table_height_above_floor_m: float = 0.90
    tolerance_mm: int = TOLERANCE_MM

    def __post_init__(self) -> None:
        if len(self.counter_region_m) != 4 or len(self.flip_area_center_m) != 2:
            raise InvalidCell("cell: counter_region_m needs 4 numbers and flip_area_center_m 2")
        values = (*self.counter_region_m, *self.flip_area_center_m, self.flip_area_radius_m)
        if not all(math.isfinite(v) for v in values):
            raise InvalidCell("cell: every coordinate must be a finite number of metres")
        x0, y0, x1, y1 = self.counter_region_m
        if not (x1 > x0 and y1 > y0):
            raise InvalidCell(
                f"cell.counter_region_m: {list(self.counter_region_m)} is not [x_min, y_min, x_max, y_max] "
                "with min < max"
            )
        if not self.flip_area_radius_m > 0:
            raise InvalidCell(f"cell.flip_area_radius_m: {self.flip_area_radius_m} must be > 0")
        if not (math.isfinite(self.table_height_above_floor_m) and self.table_height_above_floor_m > 0):
            raise InvalidCell(
                f"cell.table_height_above_floor_m: {self.table_height_above_floor_m} must be > 0"
            )
        if self.tolerance_mm < 0:
            raise InvalidCell(f"planner.tolerance_mm: {self.tolerance_mm} must be >= 0")

    def with_tray(self, tray: Tray) -> CellLayout:
        """The same cell with another tray (a simulated counter set up for a full-size-tray dataset)."""
        return replace(self, tray=tray)

    @property
    def table_region_m(self) -> tuple[float, float, float, float]:
        """The table top: everything on it (counter, flip area, tray with walls, arm base) plus a margin."""
        cx0, cy0, cx1, cy1 = self.counter_region_m
        tx0, ty0, tx1, ty1 = self.tray.outer_region_m
        fx, fy = self.flip_area_center_m
        fr = self.flip_area_radius_m
        b = _ARM_BASE_HALF_M
        x0 = min(cx0, tx0, fx - fr, -b)
        y0 = min(cy0, ty0, fy - fr, -b)
        x1 = max(cx1, tx1, fx + fr, b)
        y1 = max(cy1, ty1, fy + fr, b)
        m = TABLE_MARGIN_M
        return x0 - m, y0 - m, x1 + m, y1 + m

    def mug_base_z_m(self, x_m: float, y_m: float) -> float:
        """Height of the surface a mug standing at (x, y) rests on: the tray base inside the tray, else 0."""
        return self.tray.base_m if self.tray.contains(x_m, y_m) else 0.0


def thesis_camera_pose(cell: CellLayout) -> tuple[float, float, float]:
    """(height above the floor, horizontal distance to the nearest table edge, pitch) of the cell's camera,
    for checking it against §5.3.3 (170 cm, 70 cm, 55°)."""
    x, y, z = cell.camera.position_m
    x0, y0, x1, y1 = cell.table_region_m
    dx = max(x0 - x, 0.0, x - x1)
    dy = max(y0 - y, 0.0, y - y1)
    return z + cell.table_height_above_floor_m, math.hypot(dx, dy), cell.camera.pitch_rad


THESIS_CAMERA_POSE: Final = (CAMERA_HEIGHT_M, CAMERA_DISTANCE_TO_TABLE_M, CAMERA_PITCH_RAD)
