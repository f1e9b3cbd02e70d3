"""Packing mug-shaped footprints (``shapes``): fill heuristics on a fine grid of brim positions.

Every mug class (type and handle angle to the slot's bearing) has a grid of candidate footprint corners,
``GRID_MM`` apart plus the tray's far edges, and a mask of the corners where such a mug would fit: inside the
walls and clear of the mugs already on the tray. Placing a mug clears, in every class's mask, the corners
whose mug would come closer than the clearance to it; only a window of the grid around the new mug can be
affected, so one placement costs a few thousand exact distance tests per class. A fill heuristic takes the
first free corner in its scan (as §4.2.2's do on the 1 mm matrix): rows along one tray axis from one side,
each from one end.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from planning.placement.problem import Problem
from planning.placement.shapes import (
    Bodies,
    MugOutline,
    clear_of,
    keeps_clear,
)

GRID_MM = 2
# Counter mugs whose handle angles (to the slot's bearing) fall in one bin of this width share a class:
# detected yaws differ by noise, and a class per mug would multiply the packer's work.
CLASS_BIN_RAD = math.radians(2.0)
# A scan: (primary axis, slant, secondary direction). Axes 0 and 1 are the tray's x and y: corners are taken
# by the primary coordinate plus slant times the secondary one, low first (rows from the arm's side, or from
# the right), then by the secondary coordinate in the given direction. Slant 0 is the thesis's bottom-left /
# left-bottom fill; a slanted row lets a row of brims step along the handles of the row before it. The arm
# turns every handle along the slot's bearing, so two scans follow the arm's polar coordinates (of the brim
# centre, from the arm base; a bearing counts as ``BEARING_MM`` mm per radian): axis 2 fills arcs from the
# arm outwards (distance plus slant times bearing, then the bearing in the given direction), so a row's
# handles all point away from it into the gaps of the next arc; axis 3 fills radial columns from one side
# (the bearing in the given direction plus slant times distance, then the distance), handles along each
# column.
Scan = tuple[int, float, int]
# (With a slant the secondary direction hardly ever breaks a tie, so only the unslanted tray scans take both.)
SLANTS = (0.15, -0.15, 0.3, -0.3, 0.6, -0.6, 1.0, -1.0)
POLAR_SLANTS = (0.0, 0.15, -0.15, 0.3, -0.3, 0.6, -0.6)
SCANS: tuple[Scan, ...] = tuple(
    [(a, 0.0, d) for a in (0, 1) for d in (1, -1)]
    + [(a, k, 1) for k in SLANTS for a in (0, 1)]
    + [(a, k, d) for a in (2, 3) for k in POLAR_SLANTS for d in (1, -1)]
)
BEARING_MM = 500.0
# (class, corner x, corner y) of a placed mug, tray coordinates
Spot = tuple[int, int, int]

BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class MugClass:
    """Mugs that share an outline and a handle angle to the slot's bearing, so also their fitting corners."""

    type: str
    relative_rad: float
    xs: npt.NDArray[np.int64]
    ys: npt.NDArray[np.int64]
    bodies: Bodies  # arrays of shape (len(xs), len(ys))
    stacked: npt.NDArray[np.float64]  # the same arrays stacked, shape (fields, len(xs), len(ys))
    free: BoolArray  # the corners where the mug fits on the tray as the problem gives it
    ranks: dict[Scan, npt.NDArray[np.int64]]


class MugPacker:
    """Packs sequences of mug classes with a scan; see the module doc."""

    def __init__(self, problem: Problem, *, grid_mm: int = GRID_MM) -> None:
        self.problem = problem
        self.clearance = float(problem.tolerance_mm)
        half = self.clearance / 2.0
        keys: dict[tuple[str, int], int] = {}
        self.class_of: list[int] = []
        spread: dict[tuple[str, int], float] = defaultdict(float)
        for i, m in enumerate(problem.mugs):
            rel = problem.relative_yaw(i)
            key = (m.type, round(rel / CLASS_BIN_RAD))
            self.class_of.append(keys.setdefault(key, len(keys)))
            spread[key] = max(spread[key], abs(rel - key[1] * CLASS_BIN_RAD))
        tx, ty = problem.tray_size_mm
        fixed = fixed_bodies(problem)
        self.classes: list[MugClass] = []
        for (type_name, bin_index), _ in sorted(keys.items(), key=lambda kv: kv[1]):
            side = problem.mug_types[type_name].diameter_mm + problem.tolerance_mm
            xs = _axis(tx - side, grid_mm)
            ys = _axis(ty - side, grid_mm)
            rel = bin_index * CLASS_BIN_RAD
            bodies = self._grid_bodies(type_name, rel, spread[(type_name, bin_index)], xs, ys)
            free = (
                keeps_clear(bodies.wall_gap((tx, ty)), half)
                if len(xs) and len(ys)
                else np.zeros((0, 0), bool)
            )
            for k in range(len(fixed.cx)):
                free &= keeps_clear(bodies.gap_to(fixed, k), self.clearance)
            gx, gy = np.meshgrid(xs, ys, indexing="ij")
            polar = self._polar(type_name, xs, ys)
            ranks = {s: _ranks(gx, gy, s, polar) for s in SCANS}
            stacked = np.stack([getattr(bodies, f) for f in Bodies.__dataclass_fields__])
            self.classes.append(MugClass(type_name, rel, xs, ys, bodies, stacked, free, ranks))

    def _grid_bodies(
        self,
        type_name: str,
        rel: float,
        spread: float,
        xs: npt.NDArray[np.int64],
        ys: npt.NDArray[np.int64],
    ) -> Bodies:
        """The class's mug at every grid corner; a handle whose angle may be up to ``spread`` off the
        class's is thickened by how far that turns its tip, so the outline covers every mug of the class."""
        p = self.problem
        t = p.mug_types[type_name]
        r = (t.diameter_mm + p.tolerance_mm) / 2.0
        cx, cy = np.meshgrid(xs + r, ys + r, indexing="ij")
        wx, wy = cx + p.tray_origin_mm[0] - p.arm_base_mm[0], cy + p.tray_origin_mm[1] - p.arm_base_mm[1]
        yaw = np.arctan2(wy, wx) + rel
        outline = MugOutline.of(t)
        if spread > 0:
            outline = replace(outline, half_thickness=outline.half_thickness + outline.handle_to * spread)
        return Bodies.build(outline, cx.astype(float), cy.astype(float), yaw)

    def _polar(
        self, type_name: str, xs: npt.NDArray[np.int64], ys: npt.NDArray[np.int64]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The distance (mm) and bearing (rad) from the arm base of the brim centre at every grid corner."""
        p = self.problem
        r = (p.mug_types[type_name].diameter_mm + p.tolerance_mm) / 2.0
        cx, cy = np.meshgrid(xs + r, ys + r, indexing="ij")
        wx, wy = cx + p.tray_origin_mm[0] - p.arm_base_mm[0], cy + p.tray_origin_mm[1] - p.arm_base_mm[1]
        return np.hypot(wx, wy), np.arctan2(wy, wx)

    def pack(self, sequence: Sequence[int], scan: Scan) -> list[Spot]:
        """Places the classes of ``sequence`` one after the other at the first free corner of ``scan``;
        a mug that fits nowhere is skipped."""
        free = [c.free.copy() for c in self.classes]
        spots: list[Spot] = []
        for k in sequence:
            c = self.classes[k]
            if not free[k].any():
                continue
            flat = int(np.argmin(np.where(free[k], c.ranks[scan], np.iinfo(np.int64).max)))
            i, j = divmod(flat, len(c.ys))
            spots.append((k, int(c.xs[i]), int(c.ys[j])))
            self._block(free, k, i, j)
        return spots

    def _block(self, free: list[BoolArray], k: int, i: int, j: int) -> None:
        """Clears, in every class's mask, the corners too close to mug ``k`` placed at grid corner (i, j).

        Only still-free corners within reach are tested: brims closer than both radii and the clearance
        block at once, and only those between that and both outlines' extents need the exact test."""
        placed = self.classes[k].bodies
        px, py = float(placed.cx[i, j]), float(placed.cy[i, j])
        one = _one(placed, i, j)
        for q, c in enumerate(self.classes):
            if not len(c.xs) or not len(c.ys):
                continue
            offset = float(c.bodies.cx[0, 0] - c.xs[0])  # corner to brim centre
            near = float(c.bodies.r[0, 0]) + float(placed.r[i, j]) + self.clearance
            reach = float(c.bodies.extent[0, 0]) + float(placed.extent[i, j]) + self.clearance
            i0 = int(np.searchsorted(c.xs, px - reach - offset, side="left"))
            i1 = int(np.searchsorted(c.xs, px + reach - offset, side="right"))
            j0 = int(np.searchsorted(c.ys, py - reach - offset, side="left"))
            j1 = int(np.searchsorted(c.ys, py + reach - offset, side="right"))
            if i0 >= i1 or j0 >= j1:
                continue
            window = free[q][i0:i1, j0:j1]
            wi, wj = np.nonzero(window)
            if not wi.size:
                continue
            d = np.hypot(c.bodies.cx[i0 + wi, j0 + wj] - px, c.bodies.cy[i0 + wi, j0 + wj] - py)
            window[wi[d < near - 1e-6], wj[d < near - 1e-6]] = False
            ring = (d >= near - 1e-6) & (d < reach)
            ri, rj = i0 + wi[ring], j0 + wj[ring]
            if ri.size:
                candidates = Bodies(*c.stacked[:, ri, rj])
                blocked = ~clear_of(candidates, one, 0, self.clearance)
                free[q][ri[blocked], rj[blocked]] = False

    def yaw_at(self, k: int, x: int, y: int) -> float:
        c = self.classes[k]
        r = (self.problem.mug_types[c.type].diameter_mm + self.problem.tolerance_mm) / 2.0
        return self.problem.handle_yaw_on_tray(x + r, y + r, c.relative_rad)


def fixed_bodies(problem: Problem) -> Bodies:
    """The mugs already on the tray as outlines (their handles where the problem says they point)."""
    parts = []
    for q in problem.placed:
        t = problem.mug_types[q.type]
        cx, cy = problem.brim_centre_on_tray(q.type, q.x_mm, q.y_mm)
        parts.append(
            Bodies.build(MugOutline.of(t), np.array([cx]), np.array([cy]), np.array([q.handle_yaw()]))
        )
    if not parts:
        empty = np.zeros(0)
        return Bodies(*(empty for _ in Bodies.__dataclass_fields__))
    return Bodies(*(np.concatenate([getattr(b, f) for b in parts]) for f in Bodies.__dataclass_fields__))


def _axis(limit: int, step: int) -> npt.NDArray[np.int64]:
    """Corners 0, step, 2 step, ... up to ``limit``, and ``limit`` itself (a mug may touch the far wall)."""
    if limit < 0:
        return np.zeros(0, np.int64)
    values = np.arange(0, limit + 1, step, dtype=np.int64)
    if values[-1] != limit:
        values = np.append(values, np.int64(limit))
    return values


def _ranks(
    gx: npt.NDArray[np.int64],
    gy: npt.NDArray[np.int64],
    scan: Scan,
    polar: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
) -> npt.NDArray[np.int64]:
    """Each corner's place in ``scan`` (0 first); ``polar``: the brim centre's distance (mm) and bearing
    (rad) from the arm base at each corner."""
    axis, slant, direction = scan
    if axis in (0, 1):
        primary, secondary = (gx, gy) if axis == 0 else (gy, gx)
        order = np.lexsort(((direction * secondary).ravel(), (primary + slant * secondary).ravel()))
    else:
        distance, bearing = polar
        if axis == 2:
            keys = (direction * bearing, distance + slant * BEARING_MM * bearing)
        else:
            keys = (distance, direction * BEARING_MM * bearing + slant * distance)
        order = np.lexsort((keys[0].ravel(), keys[1].ravel()))
    ranks = np.empty(order.size, np.int64)
    ranks[order] = np.arange(order.size)
    return ranks.reshape(gx.shape)


def _one(b: Bodies, i: int, j: int) -> Bodies:
    return Bodies(*(np.array([getattr(b, f)[i, j]]) for f in Bodies.__dataclass_fields__))
