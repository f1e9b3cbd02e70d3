"""Mug-shaped footprints: the brim disc plus the handle, at the yaw the arm gives it.

Seen from above an upside-down mug is its brim disc (radius l / 2) and its handle, a bar from the wall out to
the mug's width w, ``HANDLE_HALF_THICKNESS_MM`` either side of its centre line: a capsule whose centre line
runs from l / 2 to w - l / 2 - t from the mug's axis. Two mugs keep ``clearance`` (the problem's tolerance)
between their shapes; every shape keeps half of it from the tray's walls, as the rectangle model does (its
footprint is the mug grown by half the tolerance on every side).

The handle's yaw is not free (``Problem.relative_yaw``, ``Problem.handle_yaw_on_tray``): the arm has no
wrist yaw, so a side grasp keeps the handle's angle to the gripper, the flip mirrors it, and the handle
lands at slot bearing + pick bearing - counter yaw (bearings from the arm base), the model
``planning.motion.CyclePlanner`` predicts ``CyclePlan.handle_yaw_rad`` with. A mug standing with its
handle away from the arm (the simulated counters) lands with it along the slot's bearing.

Distances are exact (disc to disc, disc to segment, segment to segment) and vectorised with numpy, so a
placer can test thousands of candidate spots against a placed mug at once; ``too_close`` computes the same
distances in plain floats for one mug at a time (a placer's search, where the first spot tried is usually
clear).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class MugSize(Protocol):
    """What an outline needs of a mug type (``problem.MugType`` has it; problem.py imports this module)."""

    @property
    def diameter_mm(self) -> int: ...

    @property
    def width_mm(self) -> int: ...


# Half the handle's thickness seen from above: the simulated mugs' handle capsules (sim/mujoco/scene.py,
# HANDLE_RADIUS_M) and the motion planner's handle check (HANDLE_HALF_THICKNESS_M) use the same 5 mm.
HANDLE_HALF_THICKNESS_MM = 5.0
# Distances within this of the clearance count as keeping it (float rounding of exact contacts).
_EPS_MM = 1e-6


@dataclass(frozen=True, slots=True)
class MugOutline:
    """One mug type seen from above, around its axis: brim radius, and the handle's centre line from
    ``handle_from`` to ``handle_to`` (mm from the axis) with half thickness ``half_thickness``."""

    radius: float
    handle_from: float
    handle_to: float
    half_thickness: float

    @staticmethod
    def of(t: MugSize) -> MugOutline:
        r = t.diameter_mm / 2.0
        tip = max(r, t.width_mm - r - HANDLE_HALF_THICKNESS_MM)
        return MugOutline(r, r, tip, HANDLE_HALF_THICKNESS_MM)

    @property
    def extent(self) -> float:
        """The farthest point of the outline from the mug's axis."""
        return max(self.radius, self.handle_to + self.half_thickness)

    @functools.lru_cache(maxsize=64)  # noqa: B019 (a few outlines per process, each a few hundred bytes)
    def area(self, grow: float = 0.0) -> float:
        """The area of the outline grown by ``grow`` mm (disc and handle overlap counted once).

        Both parts are symmetric about the handle's axis, so every cross-section across it is one interval
        centred on the axis: the area is the integral of twice the larger half-width."""
        big_r = self.radius + grow
        t = self.half_thickness + grow
        s = np.linspace(-big_r, self.handle_to + t, 20_001)
        disc = np.sqrt(np.clip(big_r * big_r - s * s, 0.0, None))
        along = np.clip(s, self.handle_from, self.handle_to)
        bar = np.sqrt(np.clip(t * t - (s - along) ** 2, 0.0, None))
        return float(np.trapezoid(2.0 * np.maximum(disc, bar), s))


@dataclass(frozen=True)
class Bodies:
    """Mugs as arrays (n,): brim centres, brim radii, handle segments (start and end points), handle half
    thickness, and farthest extent from the axis."""

    cx: FloatArray
    cy: FloatArray
    r: FloatArray
    ax: FloatArray
    ay: FloatArray
    bx: FloatArray
    by: FloatArray
    t: FloatArray
    extent: FloatArray

    @staticmethod
    def build(outline: MugOutline, cx: FloatArray, cy: FloatArray, yaw: FloatArray) -> Bodies:
        c, s = np.cos(yaw), np.sin(yaw)
        n = cx.shape
        return Bodies(
            cx,
            cy,
            np.full(n, outline.radius),
            cx + outline.handle_from * c,
            cy + outline.handle_from * s,
            cx + outline.handle_to * c,
            cy + outline.handle_to * s,
            np.full(n, outline.half_thickness),
            np.full(n, outline.extent),
        )

    def wall_gap(self, size_mm: tuple[int, int]) -> FloatArray:
        """The smallest distance of each mug's outline to the tray's walls (negative: outside)."""
        tx, ty = size_mm
        disc = np.minimum.reduce(
            [self.cx - self.r, tx - self.cx - self.r, self.cy - self.r, ty - self.cy - self.r]
        )
        bar = np.minimum.reduce(
            [
                np.minimum(self.ax, self.bx) - self.t,
                tx - np.maximum(self.ax, self.bx) - self.t,
                np.minimum(self.ay, self.by) - self.t,
                ty - np.maximum(self.ay, self.by) - self.t,
            ]
        )
        return np.asarray(np.minimum(disc, bar), dtype=np.float64)

    def gap_to(self, other: Bodies, k: int) -> FloatArray:
        """The distance between each mug's outline and mug ``k`` of ``other`` (0 where they touch)."""
        ox, oy, orad = other.cx[k], other.cy[k], other.r[k]
        oax, oay, obx, oby, ot = other.ax[k], other.ay[k], other.bx[k], other.by[k], other.t[k]
        discs = np.hypot(self.cx - ox, self.cy - oy) - self.r - orad
        mine_to_disc = _point_segment(ox, oy, self.ax, self.ay, self.bx, self.by) - self.t - orad
        disc_to_theirs = _point_segment(self.cx, self.cy, oax, oay, obx, oby) - self.r - ot
        bars = _segment_segment(self.ax, self.ay, self.bx, self.by, oax, oay, obx, oby) - self.t - ot
        gap = np.maximum(np.minimum.reduce([discs, mine_to_disc, disc_to_theirs, bars]), 0.0)
        return np.asarray(gap, dtype=np.float64)


def clear_of(mine: Bodies, other: Bodies, k: int, clearance: float) -> npt.NDArray[np.bool_]:
    """``keeps_clear(mine.gap_to(other, k), clearance)``, testing each part only where the parts before it
    kept clear (a placer's inner loop)."""
    ox, oy = float(other.cx[k]), float(other.cy[k])
    limit = clearance - _EPS_MM
    ok = np.hypot(mine.cx - ox, mine.cy - oy) - mine.r - other.r[k] >= limit
    idx = np.nonzero(ok)[0]
    if idx.size:
        ax, ay, bx, by = mine.ax[idx], mine.ay[idx], mine.bx[idx], mine.by[idx]
        d = _point_segment(ox, oy, ax, ay, bx, by) - mine.t[idx] - other.r[k]
        keep = d >= limit
        oax, oay, obx, oby = (float(v[k]) for v in (other.ax, other.ay, other.bx, other.by))
        d = _point_segment(mine.cx[idx], mine.cy[idx], oax, oay, obx, oby) - mine.r[idx] - other.t[k]
        keep &= d >= limit
        sub = np.nonzero(keep)[0]
        if sub.size:
            bars = _segment_segment(ax[sub], ay[sub], bx[sub], by[sub], oax, oay, obx, oby)
            keep[sub] = bars - mine.t[idx][sub] - other.t[k] >= limit
        ok[idx] = keep
    return np.asarray(ok, dtype=np.bool_)


def keeps_clear(gap: FloatArray, clearance: float) -> npt.NDArray[np.bool_]:
    return gap >= clearance - _EPS_MM


def _point_segment(
    px: FloatArray | float,
    py: FloatArray | float,
    ax: FloatArray | float,
    ay: FloatArray | float,
    bx: FloatArray | float,
    by: FloatArray | float,
) -> FloatArray:
    dx, dy = np.subtract(bx, ax), np.subtract(by, ay)
    rx, ry = np.subtract(px, ax), np.subtract(py, ay)
    u = np.clip((rx * dx + ry * dy) / np.maximum(dx * dx + dy * dy, 1e-12), 0.0, 1.0)
    return np.asarray(np.hypot(rx - u * dx, ry - u * dy), dtype=np.float64)


def _segment_segment(
    ax: FloatArray | float,
    ay: FloatArray | float,
    bx: FloatArray | float,
    by: FloatArray | float,
    cx: FloatArray | float,
    cy: FloatArray | float,
    dx: FloatArray | float,
    dy: FloatArray | float,
) -> FloatArray:
    """Distance between segments AB and CD (arrays broadcast elementwise): 0 where they cross, else the
    least endpoint-to-segment distance."""
    ends = np.minimum.reduce(
        [
            _point_segment(ax, ay, cx, cy, dx, dy),
            _point_segment(bx, by, cx, cy, dx, dy),
            _point_segment(cx, cy, ax, ay, bx, by),
            _point_segment(dx, dy, ax, ay, bx, by),
        ]
    )
    d1 = _cross(cx, cy, dx, dy, ax, ay)
    d2 = _cross(cx, cy, dx, dy, bx, by)
    d3 = _cross(ax, ay, bx, by, cx, cy)
    d4 = _cross(ax, ay, bx, by, dx, dy)
    crossing = (d1 * d2 < 0) & (d3 * d4 < 0)
    return np.where(crossing, 0.0, ends)


# The distances above for callers outside this module (elementwise over arrays).
point_segment = _point_segment
segment_segment = _segment_segment


def _cross(
    ox: FloatArray | float,
    oy: FloatArray | float,
    px: FloatArray | float,
    py: FloatArray | float,
    qx: FloatArray | float,
    qy: FloatArray | float,
) -> FloatArray:
    return np.asarray(
        np.subtract(px, ox) * np.subtract(qy, oy) - np.subtract(py, oy) * np.subtract(qx, ox),
        dtype=np.float64,
    )


def clear_of_all(mine: Bodies, others: Bodies, clearance: float) -> npt.NDArray[np.bool_]:
    """For each of ``mine`` (arrays (n,)): whether its outline keeps ``clearance`` from every outline of
    ``others`` (arrays (m,)); ``clear_of`` over every k of ``others`` at once (the same distances), testing
    only the pairs whose axes are closer than both extents and the clearance (the others keep it)."""
    limit = clearance - _EPS_MM
    d = np.hypot(mine.cx[:, None] - others.cx[None, :], mine.cy[:, None] - others.cy[None, :])
    near = d < mine.extent[:, None] + others.extent[None, :] + clearance
    i, k = np.nonzero(near)
    if not i.size:
        return np.ones(mine.cx.shape, dtype=np.bool_)
    ox, oy, orad, ot = others.cx[k], others.cy[k], others.r[k], others.t[k]
    oax, oay, obx, oby = others.ax[k], others.ay[k], others.bx[k], others.by[k]
    cx, cy, r, t = mine.cx[i], mine.cy[i], mine.r[i], mine.t[i]
    ax, ay, bx, by = mine.ax[i], mine.ay[i], mine.bx[i], mine.by[i]
    ok = d[i, k] - r - orad >= limit
    ok &= _point_segment(ox, oy, ax, ay, bx, by) - t - orad >= limit
    ok &= _point_segment(cx, cy, oax, oay, obx, oby) - r - ot >= limit
    ok &= _segment_segment(ax, ay, bx, by, oax, oay, obx, oby) - t - ot >= limit
    clear = np.ones(mine.cx.shape, dtype=np.bool_)
    clear[i[~ok]] = False
    return clear


# One mug for the scalar test (``clear_of_each``): the ``Bodies`` fields (cx, cy, r, ax, ay, bx, by, t,
# extent), then the handle's direction (bx - ax, by - ay), its squared length (at least 1e-12), its middle
# and half its length.
Row = tuple[
    float, float, float, float, float, float, float, float, float, float, float, float, float, float, float
]
# A part is tested exactly unless a bound (the triangle inequality through a handle's middle) shows it
# keeps the clearance by this much more than float rounding could take away.
_BOUND_MARGIN_MM = 1e-9


def row(fields: Sequence[float]) -> Row:
    """A mug's ``Bodies`` fields (in their order) as a ``Row``."""
    cx, cy, r, ax, ay, bx, by, t, extent = fields
    dx, dy = bx - ax, by - ay
    return (
        cx,
        cy,
        r,
        ax,
        ay,
        bx,
        by,
        t,
        extent,
        dx,
        dy,
        max(dx * dx + dy * dy, 1e-12),
        (ax + bx) / 2.0,
        (ay + by) / 2.0,
        math.hypot(dx, dy) / 2.0,
    )


def clear_of_each(mine: Row, others: Sequence[Row], clearance: float) -> bool:
    """Whether one mug's outline keeps ``clearance`` from every outline of ``others``: ``clear_of_all`` for
    a single mug, in plain floats (a placer's first candidate is usually clear, and for one mug numpy's
    per-call cost is most of the work)."""
    return too_close(mine, others, clearance) < 0


def too_close(mine: Row, others: Sequence[Row], clearance: float) -> int:
    """The index of the first of ``others`` whose outline comes closer than ``clearance`` to ``mine``'s,
    -1 if none does (``clear_of_each``). The same distances in the same order of operations as
    ``clear_of_all``; a handle's distance is only skipped where its middle is so far that the handle keeps
    the clearance anyway (by ``_BOUND_MARGIN_MM`` more)."""
    cx, cy, r, ax, ay, bx, by, t, extent, dx, dy, l2, mx, my, half = mine
    limit = clearance - _EPS_MM
    safe = limit + _BOUND_MARGIN_MM
    hypot = math.hypot
    for k, (ocx, ocy, orad, oax, oay, obx, oby, ot, oext, odx, ody, ol2, omx, omy, ohalf) in enumerate(
        others
    ):
        d = hypot(cx - ocx, cy - ocy)
        if d >= extent + oext + clearance:
            continue
        if d - r - orad < limit:
            return k
        if (
            hypot(ocx - mx, ocy - my) - half - t - orad < safe
            and _ps(ocx, ocy, ax, ay, dx, dy, l2) - t - orad < limit
        ):
            return k
        if (
            hypot(cx - omx, cy - omy) - ohalf - r - ot < safe
            and _ps(cx, cy, oax, oay, odx, ody, ol2) - r - ot < limit
        ):
            return k
        if hypot(mx - omx, my - omy) - half - ohalf - t - ot >= safe:
            continue
        # the handles: 0 where they cross (each one's ends strictly on both sides of the other), else the
        # least distance of an end to the other handle
        d1 = odx * (ay - oay) - ody * (ax - oax)
        d2 = odx * (by - oay) - ody * (bx - oax)
        d3 = dx * (oay - ay) - dy * (oax - ax)
        d4 = dx * (oby - ay) - dy * (obx - ax)
        if d1 * d2 < 0 and d3 * d4 < 0:
            bars = 0.0
        else:
            bars = min(
                _ps(ax, ay, oax, oay, odx, ody, ol2),
                _ps(bx, by, oax, oay, odx, ody, ol2),
                _ps(oax, oay, ax, ay, dx, dy, l2),
                _ps(obx, oby, ax, ay, dx, dy, l2),
            )
        if bars - t - ot < limit:
            return k
    return -1


def near_rows(x: float, y: float, reach: float, rows: Sequence[Row]) -> list[Row]:
    """The ``rows`` that could come within the clearance of a mug whose extent plus the clearance is
    ``reach`` and whose axis is anywhere within ``NEAR_SLACK_MM`` of (x, y); ``clear_of_each`` skips
    the others at once, so a placer may test such mugs against these alone."""
    bound = reach + NEAR_SLACK_MM + _BOUND_MARGIN_MM
    return [o for o in rows if math.hypot(o[0] - x, o[1] - y) < o[8] + bound]


# How far a candidate may lie from the point ``near_rows`` was taken at.
NEAR_SLACK_MM = 30.0


def _ps(px: float, py: float, ax: float, ay: float, dx: float, dy: float, l2: float) -> float:
    """``_point_segment`` for one point and one segment from (ax, ay) along (dx, dy), ``l2`` its squared
    length (at least 1e-12)."""
    rx, ry = px - ax, py - ay
    u = (rx * dx + ry * dy) / l2
    if u <= 0.0:
        return math.hypot(rx, ry)
    if u >= 1.0:
        u = 1.0
    return math.hypot(rx - u * dx, ry - u * dy)
