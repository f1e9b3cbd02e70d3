"""What inverse kinematics is asked for and what it answers."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from drivers.interfaces import FloatArray


class GraspKind(StrEnum):
    """How the gripper meets the target. ``side`` grasps approach horizontally along the line from the
    shoulder axis (thesis Eq 4.28: the arm has no wrist yaw), fingers closing horizontally with the mug on
    the left of the approach (Eq 4.37); ``side-upside-down`` is the same with the wrist turned by pi, the
    mug on the right."""

    POSITION = "position"
    SIDE = "side"
    SIDE_UPSIDE_DOWN = "side-upside-down"


@dataclass(frozen=True, slots=True)
class GraspTarget:
    """A grasp point in the world frame (metres) and the gripper orientation its kind implies."""

    position_m: tuple[float, float, float]
    kind: GraspKind = GraspKind.POSITION

    @property
    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in self.position_m)

    def approach(self) -> FloatArray | None:
        """Unit approach direction: horizontal and radial for side grasps (Eq 4.28); None: position only."""
        if self.kind is GraspKind.POSITION:
            return None
        x, y, _ = self.position_m
        alpha = math.atan2(y, x)
        return np.array([math.cos(alpha), math.sin(alpha), 0.0])

    def rotation(self) -> FloatArray | None:
        """World rotation of the grasp frame (columns x, y, z; z = approach, y towards the mug axis), or None.

        Side grasp: x points down, so y (towards the mug) points to the left of the approach. Upside down:
        the wrist is turned by pi about the approach, x points up and the mug is on the right."""
        if self.kind is GraspKind.POSITION:
            return None
        x, y, _ = self.position_m
        alpha = math.atan2(y, x)
        z0, z1, z2 = math.cos(alpha), math.sin(alpha), 0.0  # ``approach()``
        x0, x1, x2 = 0.0, 0.0, -1.0 if self.kind is GraspKind.SIDE else 1.0
        # y = z x x, term by term as ``np.cross`` forms it (a tenth of its time; the same numbers)
        y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
        return np.array([[x0, y0, z0], [x1, y1, z1], [x2, y2, z2]])


@dataclass(frozen=True, slots=True)
class IkResult:
    """A joint solution with its residuals, or why there is none (``ok`` False, ``q`` None)."""

    ok: bool
    q: tuple[float, ...] | None
    residual_m: float
    reason: str = ""
    orientation_error_rad: float = 0.0
    iterations: int = 0
