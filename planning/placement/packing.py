"""The fast packer: the §4.2.2 heuristics on exact rectangle geometry instead of a 1 mm occupancy matrix.

In a heuristic's canonical frame (see ``heuristics``) the occupancy-matrix scan returns the lexicographically
smallest free corner (a, b). That corner always has a = 0 or a = the far edge of a rectangle already placed
(else the mug could slide one cell lower in the scan), so only those rows are tried; within a row, one sweep
over the rectangles overlapping it gives the lowest free b. The result is cell-for-cell what the matrix scan
gives (``oracle.GridPacker``; a property test holds them equal) at a fraction of the cost.

Geometry depends only on the sequence of footprints, so packings are cached by that sequence, and every
prefix is cached too: a metaheuristic's neighbour that changes position i of the order repacks from i on.
Each cached state also remembers every footprint's first fit: adding a mug only shrinks the free space, so a
first fit the new mug does not cover stays the answer, and one it covers is searched again from its row on.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass

from planning.placement.heuristics import FRAMES, Heuristic
from planning.placement.problem import Problem

# (b0, b1, a0, a1): a placed footprint in the canonical frame, half-open.
Rect = tuple[int, int, int, int]
# What is known of one footprint option's first fit in a state: (a, b, exact). Exact: it is (a, b), or the
# option fits nowhere when a < 0. Not exact: the first fit is in row a or later (a placement covered (a, b)).
_Fit = tuple[int, int, bool]
# rectangles sorted by b0, candidate rows ascending, bitmask of shapes that no longer fit, spots so far,
# first fits per footprint option (None: not computed yet)
_State = tuple[tuple[Rect, ...], tuple[int, ...], int, tuple["Spot | None", ...], tuple[_Fit | None, ...]]
# x, y (footprint corner, tray coordinates), rotated
Spot = tuple[int, int, bool]

_CACHE_LIMIT = 200_000


@dataclass(frozen=True, slots=True)
class Packing:
    """The outcome of packing one order: ``spots[k]`` is where ``order[k]`` went, or None if it did not
    fit."""

    order: tuple[int, ...]
    spots: tuple[Spot | None, ...]

    @property
    def placed(self) -> tuple[int, ...]:
        """Mug indices that fit, in packing order."""
        return tuple(m for m, s in zip(self.order, self.spots, strict=True) if s is not None)

    @property
    def unplaced(self) -> tuple[int, ...]:
        return tuple(m for m, s in zip(self.order, self.spots, strict=True) if s is None)

    @property
    def n(self) -> int:
        return sum(s is not None for s in self.spots)

    def spot_of(self) -> dict[int, Spot]:
        return {m: s for m, s in zip(self.order, self.spots, strict=True) if s is not None}


def first_fit(
    by_b: Sequence[Rect], rows: Sequence[int], size_a: int, size_b: int, da: int, db: int, from_row: int = 0
) -> tuple[int, int] | None:
    """The lowest (a, b) at which a ``da`` x ``db`` footprint fits, looking at rows from ``from_row`` on.

    ``by_b`` holds the placed rectangles as (b0, b1, a0, a1) sorted by b0; ``rows`` the ascending candidate
    rows (0 and every a1)."""
    for i in range(bisect.bisect_left(rows, from_row), len(rows)):
        a = rows[i]
        a_end = a + da
        if a_end > size_a:
            return None
        b = 0
        for b0, b1, a0, a1 in by_b:
            if a0 < a_end and a1 > a:
                if b + db <= b0:
                    break
                if b1 > b:
                    b = b1
        if b + db <= size_b:
            return a, b
    return None


class Packer:
    """Packs orders of the problem's counter mugs with one heuristic, around the mugs already on the tray."""

    def __init__(self, problem: Problem, heuristic: Heuristic) -> None:
        self.problem = problem
        self.heuristic = heuristic
        self._frame = FRAMES[heuristic]
        self._size = self._frame.sizes(problem.tray_size_mm)
        rotations = (False, True) if problem.allow_rotation else (False,)
        shapes: list[tuple[tuple[int, int, bool], ...]] = []
        shape_index: dict[tuple[tuple[int, int, bool], ...], int] = {}
        self._code: list[int] = []
        for m in problem.mugs:
            options = tuple((*problem.footprint(m.type, r), r) for r in rotations)
            if options not in shape_index:
                shape_index[options] = len(shapes)
                shapes.append(options)
            self._code.append(shape_index[options])
        # every footprint option (canonical da, db; tray fx, fy; rotated) and the options of each shape code,
        # unrotated first so that it wins ties
        self._options: list[tuple[int, int, int, int, bool]] = []
        self._shape_options: list[tuple[int, ...]] = []
        for shape in shapes:
            indices = []
            for fx, fy, rot in shape:
                option = (*self._frame.dims(fx, fy), fx, fy, rot)
                if option not in self._options:
                    self._options.append(option)
                indices.append(self._options.index(option))
            self._shape_options.append(tuple(indices))
        base = sorted(self._rect_of(*r) for r in problem.obstacle_rects())
        self._base: tuple[tuple[Rect, ...], tuple[int, ...]] = (
            tuple(base),
            tuple(sorted({0, *(r[3] for r in base)})),
        )
        # prefix of shape codes -> state after packing it
        self._cache: dict[bytes, _State] = {}
        self.placements_computed = 0

    def shape_code(self, mug: int) -> int:
        """Mugs with equal codes have equal footprints: swapping them never changes the geometry."""
        return self._code[mug]

    def _rect_of(self, x: int, y: int, fx: int, fy: int) -> Rect:
        a, b = self._frame.to_canonical(self.problem.tray_size_mm, x, y, fx, fy)
        da, db = self._frame.dims(fx, fy)
        return (b, b + db, a, a + da)

    def pack(self, order: Sequence[int]) -> Packing:
        """Place ``order`` one mug at a time; a mug that does not fit is skipped and later mugs still try."""
        key = bytes(self._code[m] for m in order)
        hit = self._cache.get(key)
        if hit is None:
            hit = self._pack_codes(key)
        return Packing(tuple(order), hit[3])

    def _pack_codes(self, key: bytes) -> _State:
        cache = self._cache
        if len(cache) > _CACHE_LIMIT:
            cache.clear()
        # The cached keys are prefix-closed, so the longest cached prefix is found by bisection.
        lo, hi = 0, len(key)
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if key[:mid] in cache:
                lo = mid
            else:
                hi = mid - 1
        if lo:
            rects_t, rows_t, failed, spots_t, fits_t = cache[key[:lo]]
        else:
            (rects_t, rows_t), failed, spots_t, fits_t = self._base, 0, (), (None,) * len(self._options)
        rects, rows, spots, fits = list(rects_t), list(rows_t), list(spots_t), list(fits_t)
        tray = self.problem.tray_size_mm
        frame = self._frame
        options = self._options
        size_a, size_b = self._size
        for k in range(lo, len(key)):
            code = key[k]
            spot: Spot | None = None
            if not failed >> code & 1:
                best: tuple[int, int, int] | None = None
                for o in self._shape_options[code]:
                    known = fits[o]
                    if known is None or not known[2]:
                        # Free space only shrinks as mugs are added, so the first fit never moves to an
                        # earlier row: start from the row it was in.
                        da, db = options[o][:2]
                        corner = first_fit(rects, rows, size_a, size_b, da, db, known[0] if known else 0)
                        self.placements_computed += 1
                        known = (corner[0], corner[1], True) if corner else (-1, -1, True)
                        fits[o] = known
                    if known[0] >= 0 and (best is None or known[:2] < best[:2]):
                        best = (known[0], known[1], o)
                if best is None:
                    failed |= 1 << code
                else:
                    a, b, o = best
                    da, db, fx, fy, rot = options[o]
                    bisect.insort(rects, (b, b + db, a, a + da))
                    k_row = bisect.bisect_left(rows, a + da)
                    if k_row == len(rows) or rows[k_row] != a + da:
                        rows.insert(k_row, a + da)
                    for p, f in enumerate(fits):
                        if f is not None and f[2] and f[0] >= 0:
                            pa, pb = f[0], f[1]
                            pda, pdb = options[p][:2]
                            if pa < a + da and a < pa + pda and pb < b + db and b < pb + pdb:
                                fits[p] = (pa, pb, False)
                    x, y = frame.from_canonical(tray, a, b, fx, fy)
                    spot = (x, y, rot)
            spots.append(spot)
            cache[key[: k + 1]] = (tuple(rects), tuple(rows), failed, tuple(spots), tuple(fits))
        return cache[key] if key else (tuple(rects), tuple(rows), failed, (), tuple(fits))
