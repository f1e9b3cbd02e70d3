"""A placing order in which the gripper never meets a mug placed earlier (§4.2.2 Fig 4.4, §5.3.3 Fig 5.12).

The arm reaches every spot from the tray edge nearest its base (x = 0). A mug A is in the way of a later mug
B when A lies between B and that edge within B's lane (A's far x edge at or below B's near x edge, y ranges
overlapping). Placing mugs by non-increasing far edge (the relative Top-Left order inside the tray, ties to
the left first) never places such an A before its B, whatever heuristic or solver produced the layout.
"""

from __future__ import annotations

from collections.abc import Sequence

# (mug index, x, y, footprint along x, footprint along y)
Footprint = tuple[int, int, int, int, int]


def execution_order(footprints: Sequence[Footprint]) -> list[int]:
    """Mug indices in a collision-free placing order: far edge first, then left (large y) first."""
    return [f[0] for f in sorted(footprints, key=lambda f: (-(f[1] + f[3]), -(f[2] + f[4]), f[0]))]


def blocking_violations(footprints_in_order: Sequence[Footprint]) -> list[tuple[int, int]]:
    """Pairs (earlier, later) where the earlier mug stands between the arm and the later one; [] when safe."""
    bad = []
    for i, a in enumerate(footprints_in_order):
        for b in footprints_in_order[i + 1 :]:
            lanes_overlap = a[2] < b[2] + b[4] and b[2] < a[2] + a[4]
            if lanes_overlap and a[1] + a[3] <= b[1]:
                bad.append((a[0], b[0]))
    return bad
