"""The arm's side-grasp workspace (thesis §4.3, appendix A's z levels) and the tray it can serve.

The thesis searched the workspace in Gazebo by moving limits 1 cm at a time. Here the arm model answers
directly: the arm turns about its shoulder axis, so whether a mug standing at (x, y) can be side-grasped at
a given height depends only on its distance from that axis (a radial profile found by IK at 2 mm steps)
and on the bearing the approach needs (Eq 4.28, Eq 4.35), which the shoulder-turn range limits. From the
profiles follows the largest tray, centred on the arm's x axis, whose every mug position can be served —
the model's answer to Eq 4.40-4.45 (33.2 x 37.4 cm in the thesis) — and a top-view PNG of the regions with
the configured cell drawn over them, with axes in mm, a scale bar, a title and a legend.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from description import thesis
from description.arm import JOINT_LIMITS
from description.cell import CellLayout
from description.thesis import MugSpec
from drivers.interfaces import FloatArray
from planning.arm.grasp import lateral_offset_m, side_grasp
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind
from planning.motion.cell import carry_height_m
from planning.motion.collision import BASE_COLUMN, CollisionWorld

_STEP_M = 0.01
_RESOLUTION_M = 0.0005
_MAX_RADIUS_M = 1.0


@dataclass(frozen=True, slots=True)
class RadialProfile:
    """Distances of the mug axis from the shoulder axis at which one grasp works (all levels given)."""

    kind: GraspKind
    spec: MugSpec
    heights_m: tuple[float, ...]
    intervals_m: tuple[tuple[float, float], ...]  # reachable [from, to], ascending

    @property
    def interval_m(self) -> tuple[float, float] | None:
        """The (first, last) reachable distance, or None when nothing is reachable."""
        if not self.intervals_m:
            return None
        return self.intervals_m[0][0], self.intervals_m[-1][1]

    def contains(self, r: FloatArray) -> FloatArray:
        """Whether distances ``r`` are reachable."""
        inside = np.zeros(np.shape(r), dtype=bool)
        for lo, hi in self.intervals_m:
            inside |= (r >= lo) & (r <= hi)
        return inside


def radial_profile(
    arm: ArmModel,
    spec: MugSpec,
    kind: GraspKind,
    heights_m: Sequence[float],
    *,
    step_m: float = _STEP_M,
    resolution_m: float = _RESOLUTION_M,
) -> RadialProfile:
    """Which axis distances (bearing 0) the grasp reaches at every one of ``heights_m``: a scan every
    ``step_m``, each change between reachable and not refined by bisection to ``resolution_m``."""
    delta = lateral_offset_m(spec, arm.gripper)
    # Reaching back over the shoulder can put the wrist into the arm's own base: those poses do not count.
    base = CollisionWorld(arm, [BASE_COLUMN], [])
    opened = arm.gripper.aperture_m(JOINT_LIMITS["gripper"].lower_rad)

    def ok(r: float) -> bool:
        for z in heights_m:
            target = side_grasp(r, 0.0, spec, arm.gripper, z_m=z, kind=kind).target
            result = arm.ik(target)
            if not result.ok or result.q is None:
                return False
            if base.first_collision(np.array([result.q]), aperture_m=opened):
                return False
        return True

    radii = np.arange(abs(delta) + step_m, _MAX_RADIUS_M, step_m)
    flags = [ok(float(r)) for r in radii]
    intervals: list[tuple[float, float]] = []
    start: float | None = None
    for i, (r, good) in enumerate(zip(radii, flags, strict=True)):
        if good and start is None:
            start = float(r) if i == 0 else _edge(ok, float(radii[i - 1]), float(r), resolution_m)
        if not good and start is not None:
            intervals.append((start, _edge(ok, float(r), float(radii[i - 1]), resolution_m)))
            start = None
    if start is not None:
        intervals.append((start, float(radii[-1])))
    return RadialProfile(kind, spec, tuple(heights_m), tuple(intervals))


def _edge(ok: Callable[[float], bool], bad: float, good: float, resolution: float) -> float:
    """The reachable end of [bad, good] to within ``resolution`` (bisection)."""
    while abs(good - bad) > resolution:
        mid = (bad + good) / 2
        if ok(mid):
            good = mid
        else:
            bad = mid
    return good


def reachable_axes(arm: ArmModel, profile: RadialProfile, x: FloatArray, y: FloatArray) -> FloatArray:
    """Whether mugs standing at (x, y) (arrays) are reachable: distance in the profile and the approach
    bearing inside the shoulder-turn range."""
    r = np.hypot(x, y)
    delta = lateral_offset_m(profile.spec, arm.gripper)
    sign = 1.0 if profile.kind is GraspKind.SIDE else -1.0
    with np.errstate(invalid="ignore"):
        alpha = np.arctan2(y, x) - sign * np.arcsin(np.clip(delta / np.maximum(r, 1e-9), -1.0, 1.0))
    turn_ok = (alpha >= arm.lower[0]) & (alpha <= arm.upper[0])
    return np.asarray(profile.contains(r) & turn_ok & (r > abs(delta)), dtype=bool)


@dataclass(frozen=True, slots=True)
class Workspace:
    """Radial profiles of every grasp the cycle uses, per mug type."""

    pick: dict[str, RadialProfile]  # side grasp at grasp and carry height (counter)
    place: dict[str, RadialProfile]  # upside-down grasp at place and carry height (tray)
    carry_z_m: float


def workspace(arm: ArmModel, catalogue: Mapping[str, MugSpec], *, tray_floor_m: float = 0.0) -> Workspace:
    """The profiles of the pick and place grasps at the thesis's z levels (appendix A: 6 cm, carry)."""
    tallest = max(m.height_mm for m in catalogue.values()) / 1000.0
    carry = carry_height_m(tallest + max(0.0, tray_floor_m))
    pick = {
        n: radial_profile(arm, m, GraspKind.SIDE, (thesis.GRASP_HEIGHT_M, carry))
        for n, m in catalogue.items()
    }
    place_z = tray_floor_m + thesis.PLACE_HEIGHT_M
    place = {
        n: radial_profile(arm, m, GraspKind.SIDE_UPSIDE_DOWN, (place_z, carry)) for n, m in catalogue.items()
    }
    return Workspace(pick, place, carry)


@dataclass(frozen=True, slots=True)
class TrayLimits:
    """The largest tray centred on the arm's x axis whose every mug position the arm serves."""

    x_near_m: float
    x_far_m: float
    half_width_m: float

    @property
    def size_mm(self) -> tuple[int, int]:
        return round((self.x_far_m - self.x_near_m) * 1000), round(2 * self.half_width_m * 1000)


def served_tray(
    arm: ArmModel, ws: Workspace, catalogue: Mapping[str, MugSpec], *, tolerance_mm: int = thesis.TOLERANCE_MM
) -> TrayLimits | None:
    """Search trays (1 cm steps) for the one of largest area all of whose mug positions are reachable."""
    best: tuple[float, TrayLimits] | None = None
    min_half = max(m.diameter_mm / 2000.0 + tolerance_mm / 2000.0 for m in catalogue.values()) + 0.001
    for x_near in np.arange(0.10, 0.70, 0.01):
        for x_far in np.arange(x_near + 0.15, 0.80, 0.01):
            lo, hi = min_half, 0.50
            if not _tray_ok(arm, ws, catalogue, x_near, x_far, lo, tolerance_mm):
                break  # a longer tray from the same near edge cannot fit either
            while hi - lo > 0.005:
                mid = (lo + hi) / 2
                lo, hi = (
                    (mid, hi) if _tray_ok(arm, ws, catalogue, x_near, x_far, mid, tolerance_mm) else (lo, mid)
                )
            area = (x_far - x_near) * 2 * lo
            if best is None or area > best[0] + 1e-9:
                best = (area, TrayLimits(float(x_near), float(x_far), float(lo)))
    return best[1] if best else None


def _tray_ok(
    arm: ArmModel,
    ws: Workspace,
    catalogue: Mapping[str, MugSpec],
    x_near: float,
    x_far: float,
    half_width: float,
    tolerance_mm: int,
) -> bool:
    tol = tolerance_mm / 1000.0
    for name, mug in catalogue.items():
        r = mug.diameter_mm / 2000.0
        ax0 = x_near + r + tol / 2
        ax1 = x_far - (mug.width_mm / 1000.0 - r + tol / 2)
        ay = half_width - r - tol / 2
        if ax1 < ax0 or ay < 0:
            return False
        xs, ys = (
            np.asarray(a, dtype=np.float64)
            for a in np.meshgrid(np.linspace(ax0, ax1, 12), np.linspace(-ay, ay, 12))
        )
        if not np.all(reachable_axes(arm, ws.place[name], xs, ys)):
            return False
    return True


@dataclass(frozen=True, slots=True)
class WorkspacePicture:
    """The top view as PNG bytes, with its title and, in words, everything written on it (its legend, axes,
    scale), for the PNG's text chunks."""

    png: bytes
    title: str
    texts: tuple[str, ...]


_LEFT_PX, _TOP_PX, _BOTTOM_PX, _RIGHT_PX = 90, 56, 70, 400  # margins: axes, title, legend
_TICK_M = 0.2
_SCALE_M = 0.1


def workspace_picture(
    arm: ArmModel,
    cell: CellLayout,
    ws: Workspace,
    *,
    px_per_m: float = 800.0,
) -> WorkspacePicture:
    """A top view: where every mug type can be picked (green) and placed upside down (blue), with the
    counter region, the flip area, the tray and the arm's base drawn over it, axes in mm, a scale bar, a
    title and a legend."""
    import cv2

    x0, x1, y0, y1 = -0.80, 0.80, -0.80, 0.80
    width = int((y1 - y0) * px_per_m)
    height = int((x1 - x0) * px_per_m)
    # Image rows run along -x (forward is up), columns along -y (left is left).
    cols, rows = np.meshgrid(np.arange(width), np.arange(height))
    wx = np.asarray(x1 - (rows + 0.5) / px_per_m, dtype=np.float64)
    wy = np.asarray(y1 - (cols + 0.5) / px_per_m, dtype=np.float64)
    pick = np.logical_and.reduce([reachable_axes(arm, p, wx, wy) for p in ws.pick.values()])
    place = np.logical_and.reduce([reachable_axes(arm, p, wx, wy) for p in ws.place.values()])
    picture = np.full((height + _TOP_PX + _BOTTOM_PX, width + _LEFT_PX + _RIGHT_PX, 3), 255, dtype=np.uint8)
    image = picture[_TOP_PX : _TOP_PX + height, _LEFT_PX : _LEFT_PX + width]  # the map: a view into it
    pick_colour, place_colour, both_colour = (200, 240, 200), (240, 215, 190), (220, 230, 200)
    image[pick] = pick_colour
    image[place] = place_colour
    image[pick & place] = both_colour
    font = cv2.FONT_HERSHEY_SIMPLEX
    texts: list[str] = []

    def px(x: float, y: float) -> tuple[int, int]:
        return round((y1 - y) * px_per_m), round((x1 - x) * px_per_m)

    def put(text: str, at: tuple[int, int], colour: tuple[int, int, int], scale: float = 0.5) -> None:
        cv2.putText(picture, text, at, font, scale, colour, 1, cv2.LINE_AA)
        texts.append(text)

    grey, dark = (200, 200, 200), (60, 60, 60)
    for r in np.arange(_SCALE_M, x1 + 1e-9, _SCALE_M):
        cv2.circle(image, px(0, 0), int(r * px_per_m), (225, 225, 225), 1, cv2.LINE_AA)
    cv2.line(image, px(x1, 0), px(x0, 0), grey, 1)
    cv2.line(image, px(0, y1), px(0, y0), grey, 1)
    counter, tray, flip = (40, 120, 40), (160, 80, 20), (30, 30, 180)
    cx0, cy0, cx1, cy1 = cell.counter_region_m
    cv2.rectangle(image, px(cx1, cy1), px(cx0, cy0), counter, 2)
    tx0, ty0, tx1, ty1 = cell.tray.region_m
    cv2.rectangle(image, px(tx1, ty1), px(tx0, ty0), tray, 2)
    fx, fy = cell.flip_area_center_m
    cv2.circle(image, px(fx, fy), int(cell.flip_area_radius_m * px_per_m), flip, 2, cv2.LINE_AA)
    cv2.circle(image, px(0, 0), int(0.05 * px_per_m), dark, -1, cv2.LINE_AA)
    for text, colour, (u, v) in (
        ("counter region", counter, px(cx1, cy1)),
        ("tray", tray, px(tx1, ty1)),
        ("flip area", flip, px(fx + cell.flip_area_radius_m, fy + cell.flip_area_radius_m)),
    ):
        put(text, (_LEFT_PX + u + 4, _TOP_PX + max(14, v - 6)), colour)
    # Axes: x (forward) up the left edge, y (the arm's left) along the bottom, both in mm.
    cv2.rectangle(picture, (_LEFT_PX, _TOP_PX), (_LEFT_PX + width, _TOP_PX + height), dark, 1)
    for k in range(round(x0 / _TICK_M), round(x1 / _TICK_M) + 1):
        u, v = px(k * _TICK_M, k * _TICK_M)
        label = f"{round(k * _TICK_M * 1000)}"
        cv2.line(picture, (_LEFT_PX - 6, _TOP_PX + v), (_LEFT_PX, _TOP_PX + v), dark, 1)
        put(label, (_LEFT_PX - 10 - 9 * len(label), _TOP_PX + v + 5), dark, 0.45)
        cv2.line(picture, (_LEFT_PX + u, _TOP_PX + height), (_LEFT_PX + u, _TOP_PX + height + 6), dark, 1)
        put(label, (_LEFT_PX + u - 5 * len(label), _TOP_PX + height + 22), dark, 0.45)
    put("x (mm, forward)", (6, _TOP_PX - 10), dark)
    put("y (mm, to the arm's left)", (_LEFT_PX + width // 2 - 110, _TOP_PX + height + 52), dark)
    # A scale bar in the map's lower right corner.
    bar = round(_SCALE_M * px_per_m)
    right, bottom = _LEFT_PX + width - 20, _TOP_PX + height - 20
    cv2.line(picture, (right - bar, bottom), (right, bottom), (0, 0, 0), 3)
    put(f"{round(_SCALE_M * 1000)} mm", (right - bar // 2 - 28, bottom - 10), (0, 0, 0))
    title = f"dishbot arm workspace: top view at the carry height {ws.carry_z_m * 100:.1f} cm"
    cv2.putText(picture, title, (_LEFT_PX, 34), font, 0.8, (0, 0, 0), 2, cv2.LINE_AA)
    # The legend, right of the map.
    lx, ly = _LEFT_PX + width + 24, _TOP_PX + 10
    put("legend", (lx, ly + 14), (0, 0, 0), 0.6)
    swatches = [
        (pick_colour, "pick reachable: side grasp, every mug type"),
        (place_colour, "place reachable: upside-down grasp"),
        (both_colour, "pick and place reachable"),
    ]
    for i, (colour, text) in enumerate(swatches):
        top = ly + 34 + 30 * i
        cv2.rectangle(picture, (lx, top), (lx + 22, top + 18), colour, -1)
        cv2.rectangle(picture, (lx, top), (lx + 22, top + 18), grey, 1)
        put(text, (lx + 32, top + 14), dark, 0.45)
    outlines = [
        (counter, "counter region (mugs start here)"),
        (tray, "tray"),
        (flip, "flip area"),
        (dark, "arm base (shoulder axis at 0, 0)"),
        ((225, 225, 225), f"rings every {round(_SCALE_M * 1000)} mm from the base"),
    ]
    for i, (colour, text) in enumerate(outlines):
        top = ly + 34 + 30 * (len(swatches) + i)
        cv2.rectangle(picture, (lx, top), (lx + 22, top + 18), colour, 2)
        put(text, (lx + 32, top + 14), dark, 0.45)
    note = ly + 34 + 30 * (len(swatches) + len(outlines)) + 10
    put("grasps at 6 cm and at the carry height", (lx, note), dark, 0.45)
    ok, encoded = cv2.imencode(".png", picture)
    if not ok:
        raise RuntimeError("png: OpenCV could not encode the workspace picture")
    return WorkspacePicture(bytes(encoded.tobytes()), title, tuple(texts))


def describe(ws: Workspace) -> list[tuple[str, str, str, str]]:
    """Rows (grasp, mug type, heights, reachable distances) for a printed summary."""
    rows = []
    for what, profiles in (("side (pick)", ws.pick), ("upside-down (place)", ws.place)):
        for name, p in profiles.items():
            heights = ", ".join(f"{z * 100:.1f}" for z in p.heights_m) + " cm"
            interval = p.interval_m
            span = "none" if interval is None else f"{interval[0]:.3f}-{interval[1]:.3f} m"
            rows.append((what, name, heights, span))
    return rows
