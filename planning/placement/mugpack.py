"""Packing mug-shaped footprints (``shapes``): fill heuristics on a fine grid of brim positions.

Every mug class (type and handle angle to the slot's bearing) has a grid of candidate footprint corners,
``GRID_MM`` apart plus the tray's far edges, and a mask of the corners where such a mug would fit: inside the
walls and clear of the mugs already on the tray. A fill heuristic takes the first corner in its scan where
the mug keeps the clearance from the mugs placed before it (as §4.2.2's do on the 1 mm matrix): rows along
one tray axis from one side, each from one end. Placing a mug clears at once, in every class's mask and a
window of the grid around it, the corners whose brims would come too close to its brim; the exact tests
against the handles run only on the corners a scan reaches (``_first_clear``), and what they reject stays
cleared for the rest of the packing. Most corners are never reached: about 45 corners per placed mug get the
exact test on datasets 1 and 4 (against the placed mugs within reach), where clearing each placed mug's
whole window tested thousands. Those tests run in plain floats, one corner at a time (``shapes.too_close``:
the first corner reached is usually clear, and numpy's cost per call was most of the work), and what they
find too close to a placed spot is kept by the packer: a later packing that places a mug on the same spot
clears those corners at once (about half the tests on datasets 1 and 2).
"""

from __future__ import annotations

import bisect
import functools
import math
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from planning.placement import cache
from planning.placement.problem import Problem
from planning.placement.shapes import (
    NEAR_SLACK_MM,
    Bodies,
    MugOutline,
    Row,
    clear_of_all,
    keeps_clear,
    near_rows,
    row,
    too_close,
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
# ``_first_clear`` tests this many free corners one at a time (plain floats) before it tests the rest in
# numpy batches of ``BATCH`` (a bound on a long search; the packings of datasets 1-6 never reach it); it
# looks for free corners ``CHUNK`` scan positions at a time, twice as many after each stretch with none
# free (up to ``MAX_CHUNK``: on a filling tray two thirds of the stretches are empty).
SCALAR_TRIES = 512
BATCH = 256
CHUNK = 1024
MAX_CHUNK = 16384
# (class, corner x, corner y) of a placed mug, tray coordinates
Spot = tuple[int, int, int]

BoolArray = npt.NDArray[np.bool_]

# A stray mug (``Problem.strays``) whose handle was not seen keeps this many handle directions clear.
_STRAY_YAWS: npt.NDArray[np.float64] = np.arange(32, dtype=np.float64) * (2.0 * np.pi / 32)


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


@dataclass(frozen=True)
class _Group:
    """The classes of one mug type: one grid of corners and brim discs, a handle per class."""

    members: tuple[int, ...]
    xs: npt.NDArray[np.int64]
    ys: npt.NDArray[np.int64]
    bx: npt.NDArray[np.float64]  # the brim centre's x of each row of corners (xs + offset)
    by: npt.NDArray[np.float64]  # and y of each column
    radius: float
    offset: float  # corner to brim centre
    # the members' ``MugClass.stacked``, shape (fields, members, len(xs) * len(ys))
    flat_stacked: npt.NDArray[np.float64]
    free: BoolArray  # the members' ``MugClass.free``, shape (members, xs, ys)
    order: dict[Scan, npt.NDArray[np.int32]]  # the flat corner indices in each scan's order
    corners: tuple[list[int], list[int]]  # xs and ys as lists (bisected for each placed mug)


class MugPacker:
    """Packs sequences of mug classes with a scan; see the module doc."""

    def __init__(self, problem: Problem, *, grid_mm: int = GRID_MM, cache_dir: Path | None = None) -> None:
        """``cache_dir``: where the scan orders are kept between runs (``cache``; None: made here)."""
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
            stacked = np.stack([getattr(bodies, f) for f in Bodies.__dataclass_fields__])
            self.classes.append(MugClass(type_name, rel, xs, ys, bodies, stacked, free))
        # each class's corners as ``shapes.Row``, made as packings test them (the same for every packing)
        self._rows: list[list[Row | None]] = [[None] * c.free.size for c in self.classes]
        # What the packings found: per spot (class, flat corner) a mug was placed on, the corners of each
        # class found too close to it. A later packing that places a mug there clears them at once.
        self._refuses: defaultdict[tuple[int, int], defaultdict[int, list[int]]] = defaultdict(
            lambda: defaultdict(list)
        )
        self._spot_of: dict[int, tuple[int, int]] = {}  # id of a placed mug's (cached) Row -> its spot
        # per placed spot (class, flat corner) and group: the window of the group's grid its brim reaches
        # and which corners there stay free (``_block_discs``; most placements are on spots placed before),
        # the windows' masks shared between spots whose brims sit alike on the grid
        self._discs: dict[tuple[int, int, int], tuple[int, int, int, int, BoolArray] | None] = {}
        self._disc_masks: dict[tuple[float, bytes, bytes], BoolArray] = {}
        # Classes of one type share the grid and the brim discs: their masks are kept and updated together.
        by_type: dict[str, list[int]] = defaultdict(list)
        for k, c in enumerate(self.classes):
            by_type[c.type].append(k)
        self.groups: list[_Group] = []
        self.group_of: dict[int, tuple[int, int]] = {}
        for members in by_type.values():
            first = self.classes[members[0]]
            for n, k in enumerate(members):
                self.group_of[k] = (len(self.groups), n)
            t = problem.mug_types[first.type]
            offset = (t.diameter_mm + problem.tolerance_mm) / 2.0
            stacked = np.stack([self.classes[k].stacked for k in members], axis=1)
            self.groups.append(
                _Group(
                    tuple(members),
                    first.xs,
                    first.ys,
                    (first.xs + offset).astype(float),
                    (first.ys + offset).astype(float),
                    t.diameter_mm / 2.0,
                    offset,
                    stacked.reshape(stacked.shape[0], len(members), -1),
                    np.stack([self.classes[k].free for k in members]).reshape(
                        len(members), len(first.xs), len(first.ys)
                    ),
                    _kept_scan_orders(
                        tx - t.diameter_mm - problem.tolerance_mm,
                        ty - t.diameter_mm - problem.tolerance_mm,
                        grid_mm,
                        offset,
                        problem.tray_origin_mm,
                        problem.arm_base_mm,
                        cache_dir,
                    ),
                    (first.xs.tolist(), first.ys.tolist()),
                )
            )

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

    def pack(self, sequence: Sequence[int], scan: Scan) -> list[Spot]:
        """Places the classes of ``sequence`` one after the other at the first free corner of ``scan``;
        a mug that fits nowhere is skipped.

        A placed mug clears at once, in its window, the corners whose brims would come too close to its
        brim (one vectorised distance per group); the exact test against the handles runs only on the
        corners a scan reaches, first ones first (``_first_clear``), and what it rejects stays cleared."""
        free = [g.free.copy() for g in self.groups]
        # per class: the scan position before which every corner is known taken (a class's corners only
        # ever get taken, so its next mug starts where its last one went)
        start = [0] * len(self.classes)
        placed: list[npt.NDArray[np.float64]] = []
        rows: list[Row] = []
        spots: list[Spot] = []
        # per step, the groups of the classes still to come: only their masks are searched again
        to_come: list[frozenset[int]] = []
        later: frozenset[int] = frozenset()
        for k in reversed(sequence):
            to_come.append(later)
            later = later | {self.group_of[k][0]}
        to_come.reverse()
        for step, k in enumerate(sequence):
            g, member = self.group_of[k]
            group = self.groups[g]
            flat = free[g][member].reshape(-1)  # a view: what _first_clear rejects stays cleared
            candidates = group.flat_stacked[:, member]
            cache = self._rows[k]
            refused: list[tuple[Row, int]] = []
            cell, start[k] = _first_clear(
                flat,
                group.order[scan],
                start[k],
                candidates,
                placed,
                self.clearance,
                rows,
                cache,
                refused,
            )
            for mug, corner in refused:
                self._refuses[self._spot_of[id(mug)]][k].append(corner)
            if cell < 0:
                continue
            i, j = divmod(cell, len(group.ys))
            spots.append((k, int(group.xs[i]), int(group.ys[j])))
            placed.append(candidates[:, cell])
            mine = cache[cell]
            if mine is None:
                mine = cache[cell] = row(candidates[:, cell].tolist())
            rows.append(mine)
            self._spot_of[id(mine)] = (k, cell)
            if not to_come[step]:
                continue
            self._block_discs(free, mine, (k, cell), to_come[step])
            for other, corners in self._refuses[(k, cell)].items():
                og, om = self.group_of[other]
                if corners and og in to_come[step]:  # what earlier packings found too close to this spot
                    free[og][om].reshape(-1)[corners] = False
        return spots

    def _block_discs(
        self, free: list[BoolArray], placed: Row, spot: tuple[int, int], groups: frozenset[int]
    ) -> None:
        """Clears, in the masks of the classes of ``groups``, the corners whose brim comes closer than both
        radii and the clearance to the brim of the mug ``placed`` (on ``spot``: the window is worked out
        once per spot and group, and kept)."""
        for g in groups:
            key = (*spot, g)
            if key not in self._discs:
                self._discs[key] = self._disc(placed, g)
            disc = self._discs[key]
            if disc is not None:
                i0, i1, j0, j1, keep = disc
                free[g][:, i0:i1, j0:j1] &= keep

    def _disc(self, placed: Row, g: int) -> tuple[int, int, int, int, BoolArray] | None:
        """The window of group ``g``'s grid (rows i0:i1, columns j0:j1) within reach of the brim of the mug
        ``placed``, and its corners whose brims keep clear of it; None when the window is empty."""
        px, py, radius = placed[0], placed[1], placed[2]
        group = self.groups[g]
        near = group.radius + radius + self.clearance
        xs, ys = group.corners
        i0 = bisect.bisect_left(xs, px - near - group.offset)
        i1 = bisect.bisect_right(xs, px + near - group.offset)
        j0 = bisect.bisect_left(ys, py - near - group.offset)
        j1 = bisect.bisect_right(ys, py + near - group.offset)
        if i0 >= i1 or j0 >= j1:
            return None
        dx, dy = group.bx[i0:i1] - px, group.by[j0:j1] - py
        shape = (near, dx.tobytes(), dy.tobytes())
        keep = self._disc_masks.get(shape)
        if keep is None:
            keep = self._disc_masks[shape] = (dx * dx)[:, None] + (dy * dy)[None, :] >= (near - 1e-6) ** 2
        return i0, i1, j0, j1, keep

    def yaw_at(self, k: int, x: int, y: int) -> float:
        c = self.classes[k]
        r = (self.problem.mug_types[c.type].diameter_mm + self.problem.tolerance_mm) / 2.0
        return self.problem.handle_yaw_on_tray(x + r, y + r, c.relative_rad)


def fixed_bodies(problem: Problem) -> Bodies:
    """The mugs already on the tray as outlines (their handles where the problem says they point), and the
    strays lying there: a stray whose handle was not seen has one in each of ``_STRAY_YAWS`` directions."""
    parts = []
    for q in problem.placed:
        t = problem.mug_types[q.type]
        cx, cy = problem.brim_centre_on_tray(q.type, q.x_mm, q.y_mm)
        parts.append(
            Bodies.build(MugOutline.of(t), np.array([cx]), np.array([cy]), np.array([q.handle_yaw()]))
        )
    for s in problem.strays:
        yaws = _STRAY_YAWS if s.handle_yaw_rad is None else np.array([s.handle_yaw_rad], dtype=np.float64)
        n = len(yaws)
        parts.append(
            Bodies.build(
                MugOutline.of(problem.mug_types[s.type]),
                np.full(n, s.brim_mm[0]),
                np.full(n, s.brim_mm[1]),
                yaws,
            )
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


@functools.lru_cache(maxsize=4)  # two types on one tray: 3-8 MB each (48 scans of 16,000-43,000 corners)
def _kept_scan_orders(
    x_limit: int,
    y_limit: int,
    grid_mm: int,
    offset: float,
    origin: tuple[float, float],
    base: tuple[float, float],
    cache_dir: Path | None,
) -> dict[Scan, npt.NDArray[np.int32]]:
    """``_scan_orders``, read from ``cache_dir`` when an earlier run kept them there (``cache``), else made
    and kept there. The orders are the same either way (a test compares them)."""
    if cache_dir is None:
        return _scan_orders(x_limit, y_limit, grid_mm, offset, origin, base)
    question = [x_limit, y_limit, grid_mm, offset, [*origin], [*base], [[*s] for s in SCANS], BEARING_MM]
    digest = cache.key(question, ("mugpack.py",), np.__version__)
    if digest is None:
        return _scan_orders(x_limit, y_limit, grid_mm, offset, origin, base)
    path = cache.orders_path(cache_dir, digest)
    size = len(_axis(x_limit, grid_mm)) * len(_axis(y_limit, grid_mm))
    try:
        kept = np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        kept = None
    if kept is not None and kept.shape == (len(SCANS), size) and kept.dtype == np.int32:
        kept.flags.writeable = False
        return {scan: kept[i] for i, scan in enumerate(SCANS)}
    orders = _scan_orders(x_limit, y_limit, grid_mm, offset, origin, base)
    stacked = np.stack([orders[scan] for scan in SCANS])
    cache.store_file(cache_dir, path.name, lambda p: np.save(p, stacked, allow_pickle=False))
    return orders


@functools.lru_cache(maxsize=4)  # two types on one tray: 3-8 MB each (48 scans of 16,000-43,000 corners)
def _scan_orders(
    x_limit: int,
    y_limit: int,
    grid_mm: int,
    offset: float,
    origin: tuple[float, float],
    base: tuple[float, float],
) -> dict[Scan, npt.NDArray[np.int32]]:
    """Every scan's order of the flat corner indices of the grid up to (``x_limit``, ``y_limit``) (corner
    to brim centre ``offset``; the tray corner at ``origin``, the arm base at ``base``, world mm). The same
    for every class of a type and every problem on the tray, so kept for the packings to come (the plan
    check's rounds and later replans in the same process).

    Each order is a lexicographic sort (primary key, then secondary key, then index: the definition, kept
    and compared in the tests), built with one stable sort of the primary key: the tray scans' over the
    corners already in secondary-key order (the grid's rows or columns), the polar scans' in the grid's
    order, ties then put in the secondary order (three, shared between the slants: bearing up, bearing down,
    distance). An unslanted tray scan needs no sort at all."""
    xs, ys = _axis(x_limit, grid_mm), _axis(y_limit, grid_mm)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    cx, cy = np.meshgrid(xs + offset, ys + offset, indexing="ij")
    wx, wy = cx + origin[0] - base[0], cy + origin[1] - base[1]
    distance, bearing = np.hypot(wx, wy).ravel(), np.arctan2(wy, wx).ravel()
    nx, ny = len(xs), len(ys)
    flat = np.arange(nx * ny, dtype=np.int64).reshape(nx, ny)
    by_row = flat.ravel()  # x, then y (then index): corner order along each row of the grid
    by_column = flat.T.ravel()  # y, then x
    # each corner's place in the polar scans' secondary orders
    by_distance = np.argsort(distance, kind="stable")
    place_by_distance = _places(by_distance)
    # an arc scan's key is the same in both directions (only its ties differ): sorted once per slant
    arc_ranks: dict[float, npt.NDArray[np.int64]] = {0.0: by_distance}
    place_by_bearing = {d: _places(np.argsort(d * bearing, kind="stable")) for d in (1, -1)}
    # a radial column scan's key is the negation of the one of the other direction and the opposite slant
    # (float negation is exact): sorted once per pair, the other one's keys in the reverse order
    column_ranks: dict[tuple[int, float], npt.NDArray[np.int64]] = {}
    orders: dict[Scan, npt.NDArray[np.int32]] = {}
    for scan in SCANS:
        axis, slant, direction = scan
        order: npt.NDArray[np.int64]
        if axis in (0, 1) and slant == 0:
            order = (flat if axis == 0 else flat.T)[:, ::direction].ravel()
        elif axis in (0, 1):
            primary, secondary = (gx, gy) if axis == 0 else (gy, gx)
            assert direction == 1  # a slanted row scan takes its rows one way (``SCANS``)
            order = _stable_by((primary + slant * secondary).ravel(), by_column if axis == 0 else by_row)
        elif axis == 2:
            key = distance + slant * BEARING_MM * bearing
            if slant not in arc_ranks:
                arc_ranks[slant] = np.argsort(key, kind="stable")
            order = _ties_by(key, place_by_bearing[direction], arc_ranks[slant].copy())
        else:
            key = direction * BEARING_MM * bearing + slant * distance
            paired = column_ranks.pop((-direction, -slant), None)
            if paired is None:
                ranks = np.argsort(key, kind="stable")
                column_ranks[(direction, slant)] = ranks.copy()
            else:
                ranks = paired[::-1].copy()
            order = _ties_by(key, place_by_distance, ranks)
        kept = order.astype(np.int32)
        kept.flags.writeable = False
        orders[scan] = kept
    return orders


def _stable_by(key: npt.NDArray[np.float64], before: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """The indices sorted by ``key``, ties in the order of ``before`` (a permutation of them)."""
    return before[np.argsort(key[before], kind="stable")]


def _places(permutation: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Each index's place in ``permutation``."""
    places = np.empty_like(permutation)
    places[permutation] = np.arange(permutation.size)
    return places


def _ties_by(
    key: npt.NDArray[np.float64],
    place: npt.NDArray[np.int64],
    ranks: npt.NDArray[np.int64] | None = None,
) -> npt.NDArray[np.int64]:
    """The indices sorted by ``key``, ties by ``place``: ``_stable_by`` for the permutation whose places
    ``place`` gives, sorting the keys in their own order (a polar key runs monotonically along much of each
    grid column, which the stable sort's runs take whole) and then only the runs of equal keys by place.
    ``ranks``: indices that sort ``key`` when the caller has them, in any order among equal keys (a
    scratch copy: it is reordered here)."""
    if ranks is None:
        ranks = np.argsort(key, kind="stable")
    ordered = key[ranks]
    tie = ordered[1:] == ordered[:-1]
    if tie.any():
        run = np.concatenate(([0], np.cumsum(~tie)))  # which run of equal keys each sorted place is in
        tied = np.zeros(ranks.size, dtype=bool)
        tied[:-1] |= tie
        tied[1:] |= tie
        at = np.flatnonzero(tied)
        some = ranks[at]
        ranks[at] = some[np.lexsort((place[some], run[at]))]
    return ranks


def _first_clear(
    free: BoolArray,
    order: npt.NDArray[np.int32],
    start: int,
    candidates: npt.NDArray[np.float64],
    placed: Sequence[npt.NDArray[np.float64]],
    clearance: float,
    rows: Sequence[Row],
    cache: list[Row | None],
    refused: list[tuple[Row, int]],
) -> tuple[int, int]:
    """The first corner in ``order`` (from position ``start``) free in ``free`` (flat) whose outline
    (``candidates``: the class's stacked body fields per flat corner) keeps ``clearance`` from every
    ``placed`` outline (stacked fields; ``rows``: the same as ``Row``); corners found too close are cleared
    in ``free``. Returns the corner (-1: none) and its position in ``order`` (where the class's next search
    starts).

    The first ``SCALAR_TRIES`` free corners are tested one at a time in plain floats (``clear_of_each``,
    against the placed mugs near them; ``cache``: the class's corners as ``Row``, filled as they are
    tested): the first is usually clear, and for one corner numpy's per-call cost would be most of the
    work; each corner found too close goes to ``refused`` with the placed mug it is too close to. Past them
    the corners go to ``clear_of_all`` in growing batches."""
    if not placed:  # nothing to keep clear of: the first free corner
        rest = free[order[start:]].nonzero()[0]
        return (int(order[start + rest[0]]), start + int(rest[0])) if rest.size else (-1, order.size)
    chunk = CHUNK
    pos = start
    tries = SCALAR_TRIES
    near: list[Row] = []
    at_x = at_y = math.inf
    hypot = math.hypot
    while tries and pos < order.size:
        idx = order[pos : pos + chunk]
        found = free[idx].nonzero()[0]  # (a 1-D array: flatnonzero without its wrappers)
        for part in range(0, found.size, 32):  # the first is usually clear: Python ints for a few at a time
            some = found[part : part + 32]
            for at, cell in zip(some.tolist(), idx[some].tolist(), strict=True):
                mine = cache[cell]
                if mine is None:
                    mine = cache[cell] = row(candidates[:, cell].tolist())
                if hypot(mine[0] - at_x, mine[1] - at_y) > NEAR_SLACK_MM:
                    at_x, at_y = mine[0], mine[1]
                    near = near_rows(at_x, at_y, mine[8] + clearance, rows)
                k = too_close(mine, near, clearance)
                if k < 0:
                    return cell, pos + at
                refused.append((near[k], cell))
                if k:  # test the next corner against this mug first: it is usually too close to it too
                    near.insert(0, near.pop(k))
                free[cell] = False
                tries -= 1
                if not tries:
                    break
            if not tries:
                pos += at + 1
                break
        else:
            pos += idx.size
            if not found.size:
                chunk = min(chunk * 2, MAX_CHUNK)
    others = Bodies(*np.array(placed).T)
    chunk = CHUNK
    batch = BATCH
    while pos < order.size:
        idx = order[pos : pos + chunk]
        found = free[idx].nonzero()[0]
        done = 0
        while done < found.size:
            take = found[done : done + batch]
            cells = idx[take]
            ok = clear_of_all(Bodies(*candidates[:, cells]), others, clearance)
            hit = np.flatnonzero(ok)
            last = int(hit[0]) if hit.size else take.size
            free[cells[:last]] = False
            if hit.size:
                return int(cells[last]), pos + int(take[last])
            done += take.size
            batch = min(batch * 2, 256)
        pos += idx.size
    return -1, order.size
