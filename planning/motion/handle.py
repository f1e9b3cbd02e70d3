"""Where a mug's handle ends up on the tray, and whether it stays clear of the tray's walls and the mugs
placed there: the packing plans with the handle along +x, and the arm cannot turn a mug about z."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from description.thesis import MugSpec
from drivers.interfaces import FloatArray
from planning.arm.model import ArmModel
from planning.interfaces import MotionRefused, MugPose, TraySlot
from planning.motion.builder import Motion
from planning.motion.scene import Scene

# A mug's handle seen from above (thesis mugs: a loop about 1 cm thick), and the room it must keep from a
# placed mug; the tolerance the packing leaves between footprints is 1 cm.
HANDLE_HALF_THICKNESS_M = 0.005
HANDLE_CLEARANCE_M = 0.002

Segment = tuple[tuple[float, float], tuple[float, float]]


def handle_yaw_on_tray(arm: ArmModel, mug: MugPose, motions: Sequence[Motion]) -> float:
    """Where the mug's handle points once placed: the mug turns with the gripper between each grasp and
    its release, so its counter yaw is carried through pick -> set-down and regrasp -> place (a mug
    already upside down: pick -> place)."""

    def grasp_rotation(phase: str) -> FloatArray:
        last = [m for m in motions if m.step.phase == phase and m.step.trajectory is not None][-1]
        assert last.step.trajectory is not None
        return arm.fk(last.step.trajectory.positions[-1])[1]

    d = np.array([math.cos(mug.handle_yaw_rad), math.sin(mug.handle_yaw_rad), 0.0])
    turns = [("side_grasp.approach", "place.descend")]
    if not mug.upside_down:
        turns = [("side_grasp.approach", "flip.set_down"), ("flip.regrasp", "place.descend")]
    for grasped, released in turns:
        d = grasp_rotation(released) @ grasp_rotation(grasped).T @ d
    return math.atan2(float(d[1]), float(d[0]))


def check_handle(
    scene: Scene, mug: MugPose, slot: TraySlot, spec: MugSpec, yaw: float, on_tray: Sequence[TraySlot]
) -> None:
    """Refuse a cycle that leaves the mug's handle in a placed mug or over the tray's wall. Seen from above
    a handle is a bar from the wall out to the mug's width, ``HANDLE_HALF_THICKNESS_M`` thick; it must keep
    ``HANDLE_CLEARANCE_M`` from every placed mug's body and handle."""
    mine = handle_bar(slot.x_m, slot.y_m, spec, yaw)
    where = f"mug {mug.mug_id}'s handle would end at {math.degrees(yaw):.0f} deg"
    x0, y0, x1, y1 = scene.cell.tray.region_m
    reach = HANDLE_HALF_THICKNESS_M
    (ax, ay), (bx, by) = mine
    if (
        min(ax, bx) - reach < x0
        or max(ax, bx) + reach > x1
        or min(ay, by) - reach < y0
        or max(ay, by) + reach > y1
    ):
        raise MotionRefused(f"place: {where}, over the tray's wall")
    body_r = spec.diameter_mm / 2000.0
    for s in on_tray:
        yaw_s = s.handle_yaw_rad if s.handle_yaw_rad is not None else (math.pi / 2 if s.rotated else 0.0)
        other = scene.spec(s.type, f"mug {s.mug_id}")
        theirs = handle_bar(s.x_m, s.y_m, other, yaw_s)
        gaps = (
            (segment_point_m(mine, (s.x_m, s.y_m)) - other.diameter_mm / 2000.0 - reach, "body"),
            (segment_point_m(theirs, (slot.x_m, slot.y_m)) - body_r - reach, "handle"),
            (segment_segment_m(mine, theirs) - 2 * reach, "handle"),
        )
        for gap, part in gaps:
            if gap < HANDLE_CLEARANCE_M:
                raise MotionRefused(
                    f"place: {where}, {max(gap, 0.0) * 1000:.0f} mm from the {part} of mug {s.mug_id}",
                    blockers=(s.mug_id,),
                )


def handle_bar(x: float, y: float, spec: MugSpec, yaw: float) -> Segment:
    """The handle's centre line from the mug's wall out to its width, for a mug standing at (x, y)."""
    r = spec.diameter_mm / 2000.0
    out = spec.width_mm / 1000.0 - r - HANDLE_HALF_THICKNESS_M
    c, s = math.cos(yaw), math.sin(yaw)
    return (x + r * c, y + r * s), (x + out * c, y + out * s)


def segment_point_m(seg: Segment, p: tuple[float, float]) -> float:
    """Distance from a point to a segment in the plane."""
    (ax, ay), (bx, by) = seg
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / length2))
    return math.hypot(p[0] - (ax + t * dx), p[1] - (ay + t * dy))


def segment_segment_m(a: Segment, b: Segment) -> float:
    """Distance between two segments in the plane: 0 when they cross, else the nearest endpoint's."""

    def side(p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]) -> float:
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    if side(*a, b[0]) * side(*a, b[1]) < 0 and side(*b, a[0]) * side(*b, a[1]) < 0:
        return 0.0
    return min(
        segment_point_m(a, b[0]),
        segment_point_m(a, b[1]),
        segment_point_m(b, a[0]),
        segment_point_m(b, a[1]),
    )
