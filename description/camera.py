"""The depth camera as the cell describes it: its pinhole model and where it stands in the world frame."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from description.arrays import FloatArray


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
            raise ValueError(f"camera width/height {self.width}x{self.height}: use at least 16x16 pixels")
        if not 10.0 <= self.fovy_deg <= 120.0:
            raise ValueError(f"camera fovy_deg {self.fovy_deg}: use a value in [10, 120] degrees")
        if not 0.0 < self.pitch_rad < math.pi / 2:
            raise ValueError(f"camera pitch_rad {self.pitch_rad}: it must look down, in (0, pi/2)")

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
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        forward = np.array([cp * cy, cp * sy, -sp])
        right = np.array([sy, -cy, 0.0])
        down = np.cross(forward, right)
        T = np.eye(4)
        T[:3, 0], T[:3, 1], T[:3, 2] = right, down, forward
        T[:3, 3] = self.position_m
        return T
