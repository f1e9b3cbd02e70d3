"""Side-grasp geometry (thesis §4.3, Eq 4.28-4.39): where the grasp point goes for a mug, and back.

The arm has no wrist yaw, so the gripper always approaches along a line through the shoulder-turn axis
(Eq 4.28). The mug's axis then sits beside that line: the thumb touches the brim, so the axis is
``r_m - w_g`` to the side of the grasp point (Eq 4.29-4.30), to the left of the approach for the side grasp
and to the right when the wrist is turned by pi (the ∓ of Eq 4.37). Solving for the approach
angle gives Eq 4.33-4.35; the palm (the thesis's gripper position) is a finger length behind the grasp
point (Eq 4.36-4.37). The inverse (Eq 4.38-4.39) maps a reachable grasp point back to the mug it holds,
which is what the tray limits (Eq 4.40-4.45) are built from.

One change from the thesis: its grasp point is the finger tip *on* the mug's widest line, so a squeeze
pushes the mug out of the gripper (the finger touches the brim with its tip corner, and a finger leaning in
wedges the mug outwards). Here the grasp point lies ``reach_past_axis_m`` further along the approach, so
the fingers wrap past the brim's centre line and a squeeze presses the mug towards the palm; how far is
bounded by the room between the mug and the palm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from description.arm import GripperGeometry
from description.thesis import MugSpec
from drivers.interfaces import FloatArray
from planning.arm.targets import GraspKind, GraspTarget


@dataclass(frozen=True, slots=True)
class SideGrasp:
    """A side grasp of one mug: the IK target and the angles of Eq 4.28-4.35 (radians)."""

    target: GraspTarget
    mug_xy_m: tuple[float, float]
    palm_xy_m: tuple[float, float]
    alpha_rad: float  # approach angle (Eq 4.28, = alpha' of Eq 4.35 with the base at the origin)
    theta_rad: float  # Eq 4.32
    delta_mg_m: float  # Eq 4.30
    reach_m: float  # how far the grasp point lies past the mug axis along the approach


# How far the finger tips reach past the mug's axis, as a fraction of its radius, and the gap kept between
# the mug and the palm plate when the mug is that deep in the gripper.
REACH_PAST_AXIS_FRACTION: Final = 0.35
PALM_GAP_M: Final = 0.003


def reach_past_axis_m(spec: MugSpec, gripper: GripperGeometry) -> float:
    """How far along the approach the finger tips (the grasp point) lie beyond the mug's axis: a third of
    the radius, less when the palm would come closer than ``PALM_GAP_M`` to the mug (big mugs: 6.7 mm)."""
    r = spec.diameter_mm / 2000.0
    room = gripper.finger_length_m - r - gripper.plate_thickness_m / 2 - PALM_GAP_M
    return max(0.0, min(REACH_PAST_AXIS_FRACTION * r, room))


def handle_facing_away_rad(x_m: float, y_m: float) -> float:
    """The yaw of a handle pointing away from the shoulder axis for a mug standing at (x, y): out of the way
    of a side grasp, which comes from behind the mug. Mugs set out that way end on the tray with the handle
    near the slot's bearing (the simulated cells' and the benchmarks' counters; the thesis's Gazebo mugs
    likewise ended "slightly rotated", §5.3.3)."""
    return math.atan2(y_m, x_m)


def lateral_offset_m(spec: MugSpec, gripper: GripperGeometry) -> float:
    """Distance between the mug axis and the grasp point, r_m - w_g (Eq 4.29-4.30)."""
    return spec.diameter_mm / 2000.0 - gripper.thumb_width_m


def _side_sign(kind: GraspKind) -> float:
    """+1 when the mug is left of the approach (side grasp), -1 when right (upside down)."""
    if kind is GraspKind.POSITION:
        raise ValueError("a side grasp needs kind 'side' or 'side-upside-down', not 'position'")
    return 1.0 if kind is GraspKind.SIDE else -1.0


def side_grasp(
    mug_x_m: float,
    mug_y_m: float,
    spec: MugSpec,
    gripper: GripperGeometry,
    *,
    z_m: float,
    kind: GraspKind = GraspKind.SIDE,
) -> SideGrasp:
    """The grasp that holds a mug standing at (x, y) with the grasp point at height ``z_m``.

    Raises ValueError when the mug axis is so close to the shoulder axis that no radial approach can pass
    beside it (|m| <= r_m - w_g)."""
    delta = lateral_offset_m(spec, gripper)
    sign = _side_sign(kind)
    dist = math.hypot(mug_x_m, mug_y_m)  # Eq 4.31 with the arm base at the origin
    if dist <= abs(delta):
        raise ValueError(f"mug at ({mug_x_m:.3f}, {mug_y_m:.3f}) is too close to the shoulder axis to grasp")
    beta = math.atan2(mug_y_m, mug_x_m)  # Eq 4.33
    gamma = math.asin(delta / dist)  # Eq 4.34
    alpha = beta - sign * gamma  # Eq 4.35: the approach line passes beside the mug axis
    reach = reach_past_axis_m(spec, gripper)
    rho = math.sqrt(dist * dist - delta * delta) + reach
    grasp_xy = (rho * math.cos(alpha), rho * math.sin(alpha))
    l_g = gripper.finger_length_m
    palm_xy = (grasp_xy[0] - l_g * math.cos(alpha), grasp_xy[1] - l_g * math.sin(alpha))
    return SideGrasp(
        target=GraspTarget((grasp_xy[0], grasp_xy[1], z_m), kind),
        mug_xy_m=(mug_x_m, mug_y_m),
        palm_xy_m=palm_xy,
        alpha_rad=alpha,
        theta_rad=math.atan2(delta, l_g),  # Eq 4.32
        delta_mg_m=math.hypot(delta, l_g),  # Eq 4.30
        reach_m=reach,
    )


def mug_axis_from_grasp(
    grasp_xy_m: tuple[float, float], spec: MugSpec, gripper: GripperGeometry, kind: GraspKind
) -> FloatArray:
    """Where the axis of a held mug is for a grasp point (Eq 4.38-4.39): beside the approach line, and
    ``reach_past_axis_m`` back along it."""
    sign = _side_sign(kind)
    alpha = math.atan2(grasp_xy_m[1], grasp_xy_m[0])
    left = np.array([-math.sin(alpha), math.cos(alpha)])
    back = -reach_past_axis_m(spec, gripper) * np.array([math.cos(alpha), math.sin(alpha)])
    return np.asarray(grasp_xy_m, dtype=np.float64) + back + sign * lateral_offset_m(spec, gripper) * left


def thesis_tray_limits(
    *,
    x_lg: float,
    x_ug: float,
    y_ug: float,
    y_ltr: float,
    delta_mg: float,
    theta: float,
    min_w_r: float,
    min_w_m: float,
) -> tuple[float, float, float, float]:
    """The tray limits (x_Ltr, x_Utr, y_Ltr, y_Utr) of Eq 4.40-4.45 from the gripper's reachable limits.

    ``min_w_r`` is the smallest mug's brim radius, ``min_w_m`` its width with the handle (the thesis's
    notation); ``y_ltr`` is chosen by the user (Eq 4.43)."""
    alpha_lx = math.atan2(y_ug, x_lg)  # Eq 4.44
    alpha_ux = math.atan2(y_ug, x_ug)  # Eq 4.45
    x_ltr = x_lg + delta_mg * math.cos(abs(alpha_lx) + theta) - min_w_r  # Eq 4.40
    x_utr = x_ug + delta_mg * math.cos(abs(alpha_ux) + theta) + min_w_m - min_w_r  # Eq 4.41
    y_utr = y_ug + delta_mg * math.sin(abs(alpha_ux) + theta) + min_w_r  # Eq 4.42
    return x_ltr, x_utr, y_ltr, y_utr
