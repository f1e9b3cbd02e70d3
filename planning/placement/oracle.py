"""The literal §4.2.2 packer: a 1 mm occupancy matrix scanned cell by cell in the heuristic's order.

It is the test oracle for ``packing.Packer`` and the baseline of ``dishbot bench placement``. The matrix has
one cell per millimetre of tray (R_om x C_om, Eq 4.12-4.13); a mug occupies ⌈(w + Δ)⌉ x ⌈(l + Δ)⌉ cells
(Eq 4.14-4.15). For each mug it works out, for every corner cell, whether all the cells the footprint would
cover are free (an integral image of the matrix does that for all corners at once), then takes the first free
corner in scan order: rows from the bottom (x = 0) or the top, each row from the left (large y) or the right,
or columns first for LBF/LTF/RBF/RTF. It shares no geometry code with the fast packer.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from planning.placement.heuristics import Heuristic
from planning.placement.packing import Packing, Spot
from planning.placement.problem import Problem

# heuristic -> (columns first?, from the top?, from the left?)
_SCANS: dict[Heuristic, tuple[bool, bool, bool]] = {
    Heuristic.BLF: (False, False, True),
    Heuristic.LBF: (True, False, True),
    Heuristic.TLF: (False, True, True),
    Heuristic.LTF: (True, True, True),
    Heuristic.BRF: (False, False, False),
    Heuristic.RBF: (True, False, False),
    Heuristic.TRF: (False, True, False),
    Heuristic.RTF: (True, True, False),
}


class GridPacker:
    """Packs orders of the problem's counter mugs on a fresh occupancy matrix each time."""

    def __init__(self, problem: Problem, heuristic: Heuristic) -> None:
        self.problem = problem
        self.heuristic = heuristic

    def pack(self, order: Sequence[int]) -> Packing:
        p = self.problem
        occupied = np.zeros(p.tray_size_mm, dtype=np.bool_)
        for x, y, fx, fy in p.obstacle_rects():
            occupied[x : x + fx, y : y + fy] = True
        rotations = (False, True) if p.allow_rotation else (False,)
        spots: list[Spot | None] = []
        for mug in order:
            best: tuple[tuple[int, int], Spot, int, int] | None = None
            for rotated in rotations:
                fx, fy = p.footprint(p.mugs[mug].type, rotated)
                found = self._first_free(occupied, fx, fy)
                if found is not None and (best is None or found[0] < best[0]):
                    best = (found[0], (found[1], found[2], rotated), fx, fy)
            if best is None:
                spots.append(None)
                continue
            _, spot, fx, fy = best
            occupied[spot[0] : spot[0] + fx, spot[1] : spot[1] + fy] = True
            spots.append(spot)
        return Packing(tuple(order), tuple(spots))

    def _first_free(
        self, occupied: npt.NDArray[np.bool_], fx: int, fy: int
    ) -> tuple[tuple[int, int], int, int] | None:
        """((scan rank primary, secondary), x, y) of the first corner in scan order where it fits."""
        size_x, size_y = occupied.shape
        if fx > size_x or fy > size_y:
            return None
        integral = np.zeros((size_x + 1, size_y + 1), dtype=np.int32)
        integral[1:, 1:] = occupied.cumsum(axis=0, dtype=np.int32).cumsum(axis=1, dtype=np.int32)
        # covered[x, y]: occupied cells under a footprint whose corner cell is (x, y)
        covered = integral[fx:, fy:] - integral[:-fx, fy:] - integral[fx:, :-fy] + integral[:-fx, :-fy]
        free = covered == 0
        columns_first, from_top, from_left = _SCANS[self.heuristic]
        # Reorder so that index order is scan order: distance from the scan's starting edges.
        if from_top:
            free = free[::-1, :]
        if from_left:
            free = free[:, ::-1]
        if columns_first:
            free = free.T
        lines = np.flatnonzero(free.any(axis=1))
        if lines.size == 0:
            return None
        first = int(lines[0])
        second = int(np.flatnonzero(free[first])[0])
        dist_x, dist_y = (second, first) if columns_first else (first, second)
        x = size_x - fx - dist_x if from_top else dist_x
        y = size_y - fy - dist_y if from_left else dist_y
        return (first, second), x, y
