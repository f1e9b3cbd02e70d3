"""The work cell: counter region, flip area, tray and camera in the world frame, and the mugs set on it.

The world frame is the daemon's: origin on the arm's shoulder-turn axis at counter height (z = 0 is the
counter top), x forward, y to the robot's left, z up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from description.camera import CameraSpec
from description.thesis import (
    CAMERA_DISTANCE_TO_TABLE_M,
    CAMERA_HEIGHT_M,
    CAMERA_PITCH_RAD,
    MugSpec,
)

MUG_PREFIX: Final = "mug/"  # every body of a mug is named under it

# The tray's base and walls (outside its inner rectangle); not thesis figures.
TRAY_BASE_M: Final = 0.006
TRAY_WALL_HEIGHT_M: Final = 0.025
TRAY_WALL_THICKNESS_M: Final = 0.008
# How far the table top reaches past everything placed on it.
TABLE_MARGIN_M: Final = 0.05


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
class SceneLayout:
    """The cell: counter region (x_min, y_min, x_max, y_max), flip area, tray corner and size, camera."""

    counter_region_m: tuple[float, float, float, float]
    flip_area_center_m: tuple[float, float]
    flip_area_radius_m: float
    tray_origin_m: tuple[float, float]
    tray_size_mm: tuple[int, int]
    camera: CameraSpec
    table_height_above_floor_m: float = 0.90

    def tray_region_m(self) -> tuple[float, float, float, float]:
        """The tray's inner area (x_min, y_min, x_max, y_max)."""
        x0, y0 = self.tray_origin_m
        return x0, y0, x0 + self.tray_size_mm[0] / 1000.0, y0 + self.tray_size_mm[1] / 1000.0

    def table_region_m(self) -> tuple[float, float, float, float]:
        """The table top: everything on it (counter, flip area, tray with walls, arm base) plus a margin."""
        cx0, cy0, cx1, cy1 = self.counter_region_m
        tx0, ty0, tx1, ty1 = self.tray_region_m()
        fx, fy = self.flip_area_center_m
        fr = self.flip_area_radius_m
        w = TRAY_WALL_THICKNESS_M
        x0 = min(cx0, tx0 - w, fx - fr, -0.08)
        y0 = min(cy0, ty0 - w, fy - fr, -0.08)
        x1 = max(cx1, tx1 + w, fx + fr, 0.08)
        y1 = max(cy1, ty1 + w, fy + fr, 0.08)
        m = TABLE_MARGIN_M
        return x0 - m, y0 - m, x1 + m, y1 + m

    def mug_base_z_m(self, x_m: float, y_m: float) -> float:
        """Height of the surface a mug standing at (x, y) rests on: the tray base inside the tray, else 0."""
        x0, y0, x1, y1 = self.tray_region_m()
        return TRAY_BASE_M if x0 <= x_m <= x1 and y0 <= y_m <= y1 else 0.0

    @classmethod
    def from_config(cls, cell: Mapping[str, object], camera: Mapping[str, object]) -> SceneLayout:
        """Build the layout from the config's ``[cell]`` and ``[camera]`` tables; ValueError names the key."""
        region = _floats(cell, "cell.counter_region_m", 4)
        flip = _floats(cell, "cell.flip_area_center_m", 2)
        tray_origin = _floats(cell, "cell.tray_origin_m", 2)
        tray_size = _floats(cell, "cell.tray_size_mm", 2)
        pos = _floats(camera, "camera.position_m", 3)
        spec = CameraSpec(
            width=int(_number(camera, "camera.width")),
            height=int(_number(camera, "camera.height")),
            fovy_deg=_number(camera, "camera.fovy_deg"),
            position_m=(pos[0], pos[1], pos[2]),
            yaw_rad=_number(camera, "camera.yaw_rad"),
            pitch_rad=_number(camera, "camera.pitch_rad"),
        )
        return cls(
            counter_region_m=(region[0], region[1], region[2], region[3]),
            flip_area_center_m=(flip[0], flip[1]),
            flip_area_radius_m=_number(cell, "cell.flip_area_radius_m"),
            tray_origin_m=(tray_origin[0], tray_origin[1]),
            tray_size_mm=(int(tray_size[0]), int(tray_size[1])),
            camera=spec,
            table_height_above_floor_m=_number(cell, "cell.table_height_above_floor_m"),
        )


def thesis_camera_pose(layout: SceneLayout) -> tuple[float, float, float]:
    """(height above the floor, horizontal distance to the nearest table edge, pitch) of the layout's camera,
    for checking it against §5.3.3 (170 cm, 70 cm, 55°)."""
    x, y, z = layout.camera.position_m
    x0, y0, x1, y1 = layout.table_region_m()
    dx = max(x0 - x, 0.0, x - x1)
    dy = max(y0 - y, 0.0, y - y1)
    return z + layout.table_height_above_floor_m, math.hypot(dx, dy), layout.camera.pitch_rad


THESIS_CAMERA_POSE: Final = (CAMERA_HEIGHT_M, CAMERA_DISTANCE_TO_TABLE_M, CAMERA_PITCH_RAD)


def _number(table: Mapping[str, object], key: str) -> float:
    value = table.get(key.split(".")[-1])
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"config {key}: expected a number, got {value!r}")
    return float(value)


def _floats(table: Mapping[str, object], key: str, n: int) -> list[float]:
    value = table.get(key.split(".")[-1])
    if (
        not isinstance(value, list | tuple)
        or len(value) != n
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise ValueError(f"config {key}: expected a list of {n} numbers, got {value!r}")
    return [float(v) for v in value]
