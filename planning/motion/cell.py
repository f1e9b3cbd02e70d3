"""The work cell as motion planning sees it: whether the arm can serve a ``description.cell.CellLayout``.

``check_reachable`` is what the daemon runs at start: the corners of the area a mug's axis can take on the
counter (mugs stand with their footprints in the counter region, so axes stay a brim radius inside it) and
its point nearest the arm, the extreme points of the flip area, and the corners and nearest point of the
axis area on the tray must be reachable with the side grasps that happen there (thesis §4.3: grasp and
release 6 cm above the table, carry and flip above the tallest mug). The side-grasp workspace is a ring
around the shoulder axis, so the nearest point matters as much as the far corners.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from description import thesis
from description.cell import CellLayout
from description.thesis import MugSpec
from planning.arm.grasp import side_grasp
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind

_CARRY_MARGIN_M = 0.005


def check_reachable(
    cell: CellLayout, arm: ArmModel, catalogue: Mapping[str, MugSpec] | None = None
) -> list[str]:
    """One line per corner of ``cell`` the arm cannot serve with every mug type of the catalogue (empty: all
    fine)."""
    mugs = list((catalogue or thesis.MUG_TYPES).values())
    tallest = max(m.height_mm for m in mugs) / 1000.0
    carry_z = carry_height_m(tallest + max(0.0, cell.tray.base_m))
    checks: list[tuple[str, tuple[float, float], Sequence[tuple[GraspKind, float]], Sequence[MugSpec]]] = []
    counter_moves = ((GraspKind.SIDE, thesis.GRASP_HEIGHT_M), (GraspKind.SIDE, carry_z))
    inset = min(m.diameter_mm for m in mugs) / 2000.0
    x0, y0, x1, y1 = cell.counter_region_m
    counter_area = (x0 + inset, y0 + inset, x1 - inset, y1 - inset)
    for corner in _corners_and_nearest(counter_area):
        checks.append(("counter point", corner, counter_moves, mugs))
    cx, cy = cell.flip_area_center_m
    r = cell.flip_area_radius_m
    # Set down upside down: the grasp point is as high above the counter as the mug is tall, less 6 cm.
    set_down_z = min(m.height_mm for m in mugs) / 1000.0 - thesis.GRASP_HEIGHT_M
    flip_moves = (
        (GraspKind.SIDE, carry_z),
        (GraspKind.SIDE_UPSIDE_DOWN, carry_z),
        (GraspKind.SIDE_UPSIDE_DOWN, max(set_down_z, 0.0)),
        (GraspKind.SIDE_UPSIDE_DOWN, thesis.GRASP_HEIGHT_M),
    )
    for point in ((cx - r, cy), (cx + r, cy), (cx, cy - r), (cx, cy + r)):
        checks.append(("flip area point", point, flip_moves, mugs))
    place_moves = (
        (GraspKind.SIDE_UPSIDE_DOWN, thesis.PLACE_HEIGHT_M),
        (GraspKind.SIDE_UPSIDE_DOWN, carry_z),
    )
    for mug in mugs:
        for corner in _corners_and_nearest(tray_axis_area(cell, mug)):
            checks.append(("tray point", corner, place_moves, [mug]))
    problems = []
    for what, (x, y), moves, specs in checks:
        for spec in specs:
            failure = _first_failure(arm, x, y, spec, moves)
            if failure:
                problems.append(f"{what} ({x:.3f}, {y:.3f}) m, {spec.name} mug: {failure}")
                break
    return problems


def tray_axis_area(cell: CellLayout, mug: MugSpec) -> tuple[float, float, float, float]:
    """The area (x_min, y_min, x_max, y_max) an unrotated mug's axis can take inside the tray: its footprint
    (handle along +x, plus the cell's tolerance) must fit."""
    tx0, ty0, tx1, ty1 = cell.tray.region_m
    tol = cell.tolerance_mm
    half_y = (mug.diameter_mm + tol) / 2000.0
    # The brim's axis is r + tol/2 from the footprint's near x edge, w - r + tol/2 from its far edge.
    near_x = mug.diameter_mm / 2000.0 + tol / 2000.0
    far_x = (mug.width_mm + tol) / 1000.0 - near_x
    return tx0 + near_x, ty0 + half_y, tx1 - far_x, ty1 - half_y


def _corners_and_nearest(area: tuple[float, float, float, float]) -> list[tuple[float, float]]:
    """The four corners of a rectangle and its point nearest the shoulder axis (if not a corner)."""
    x0, y0, x1, y1 = area
    points = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    nearest = (min(max(0.0, x0), x1), min(max(0.0, y0), y1))
    if nearest not in points:
        points.append(nearest)
    return points


def carry_height_m(tallest_mug_m: float) -> float:
    """Grasp-point height while carrying: the thesis's 7 cm above the tallest mug (§4.3), raised when needed
    so the held mug's lowest point (6 cm below the grasp point) clears the tallest mug by 3 cm, plus 5 mm
    so the clearance holds with the IK's sub-millimetre residual."""
    needed = tallest_mug_m + thesis.TRANSIT_CLEARANCE_M + thesis.GRASP_HEIGHT_M + _CARRY_MARGIN_M
    return max(tallest_mug_m + thesis.CARRY_CLEARANCE_M, needed)


def _first_failure(
    arm: ArmModel, x: float, y: float, spec: MugSpec, moves: Sequence[tuple[GraspKind, float]]
) -> str:
    for kind, z in moves:
        try:
            grasp = side_grasp(x, y, spec, arm.gripper, z_m=z, kind=kind)
        except ValueError as e:
            return str(e)
        result = arm.ik(grasp.target)
        if not result.ok:
            return f"{kind} grasp at z={z:.3f} m: {result.reason}"
    return ""
