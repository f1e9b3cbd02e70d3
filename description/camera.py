"""The depth camera as the cell describes it: its pinhole model and where it stands in the world frame."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

from description.errors import InvalidCell

if TYPE_CHECKING:
    from description.arrays import FloatArray

# The vertical field of view a camera of the cell may have (degrees).
MIN_FOVY_DEG: Final = 10.0
MAX_FOVY_DEG: Final = 120.0


@dataclass(frozen=True, slots=True)
class CameraIntrinsics:
    """Pinhole model: the camera looks along +z, x right, y down."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True, slots=True)
class CameraSpec:
    """Where the depth camera is and what it sees: image size, vertical field of view and pose.

    ``yaw_rad`` is the heading of the optical axis about +z (0 looks along +x); ``pitch_rad`` tilts it below
    the horizon. Pixels are square and the principal point is the image centre, as MuJoCo renders them.
    """

    width: int
    height: int
    fovy_deg: float
    position_m: tuple[float, float, float]
    yaw_rad: float
    pitch_rad: float

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise InvalidCell(
                f"camera.width, camera.height: {self.width}x{self.height} pixels; use at least 16x16"
            )
        if not MIN_FOVY_DEG <= self.fovy_deg <= MAX_FOVY_DEG:
            raise InvalidCell(
                f"camera.fovy_deg: {self.fovy_deg:g} is out of range; "
                f"allowed [{MIN_FOVY_DEG:g}, {MAX_FOVY_DEG:g}]"
            )
        if not 0.0 < self.pitch_rad < math.pi / 2:
            raise InvalidCell(
                f"camera.pitch_rad: {self.pitch_rad:g} does not look down; allowed (0, {math.pi / 2:g})"
            )

    def intrinsics(self) -> CameraIntrinsics:
        """The pinhole model of the rendered image (pixel indices: the first pixel's centre is (0, 0))."""
        f = (self.height / 2.0) / math.tan(math.radians(self.fovy_deg) / 2.0)
        return CameraIntrinsics(
            width=self.width,
            height=self.height,
            fx=f,
            fy=f,
            cx=(self.width - 1) / 2.0,
            cy=(self.height - 1) / 2.0,
        )

    def world_from_camera(self) -> FloatArray:
        """4×4 pose of the pinhole camera frame (z along the optical axis, x right, y down) in the world."""
        import numpy as np  # here, so that reading the config (dishbot config show) loads no numpy

        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        forward = np.array([cp * cy, cp * sy, -sp])
        right = np.array([sy, -cy, 0.0])
        down = np.cross(forward, right)
        T = np.eye(4)
        T[:3, 0], T[:3, 1], T[:3, 2] = right, down, forward
        T[:3, 3] = self.position_m
        return T
