"""Lost-mug association (thesis §4.1 Fig 4.2, §4.3.1): which of the mugs seen now is which mug seen before.

After a failed grasp or a drop the daemon looks again. A mug within 1 cm of where a known mug of the same type
was is that mug ("known"; its stored position is kept). Of the rest, the mug the arm was handling (the target)
is the closest unknown mug of its type to the robot, as in the thesis. Every other unknown mug is matched to a
remaining known mug of its type by an optimal assignment on distance (the thesis matched them greedily, which
can pair two mugs crosswise); what is left over is new, and known mugs nobody matched are lost. When anything
is lost or new, the count changed and the daemon replans, keeping the mugs already on the tray.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import overload

import numpy as np

from description.thesis import KNOWN_MUG_TOLERANCE_M
from perception.assignment import least_cost_assignment
from perception.interfaces import Detection

# Thesis §4.1, §4.3.1: a mug within this distance of its previous position has not moved.
KNOWN_WITHIN_M = KNOWN_MUG_TOLERANCE_M
# Farther than this a mug is not taken to have moved but to be another one (and the known one lost).
MAX_MOVE_M = 0.5


@dataclass(frozen=True, slots=True)
class Association(Sequence[Detection]):
    """The seen detections, each carrying the id of the known mug it is ("" when new), plus what changed.

    It is a sequence of those detections, so it can be used wherever one is expected.
    """

    detections: tuple[Detection, ...]
    kept: tuple[str, ...]  # ids seen within the tolerance of where they were
    moved: tuple[str, ...]  # ids found elsewhere (the target, or by the assignment)
    lost: tuple[str, ...]  # known ids not seen any more
    new: tuple[Detection, ...]  # seen mugs that match no known one

    @property
    def count_changed(self) -> bool:
        """True when mugs went missing or appeared: the placement must be planned again."""
        return bool(self.lost or self.new)

    @overload
    def __getitem__(self, index: int) -> Detection: ...

    @overload
    def __getitem__(self, index: slice) -> Sequence[Detection]: ...

    def __getitem__(self, index: int | slice) -> Detection | Sequence[Detection]:
        return self.detections[index]

    def __len__(self) -> int:
        return len(self.detections)

    def __iter__(self) -> Iterator[Detection]:
        return iter(self.detections)


def associate(
    known: Sequence[Detection],
    seen: Sequence[Detection],
    *,
    known_within_m: float = KNOWN_WITHIN_M,
    target_id: str = "",
    robot_xy: tuple[float, float] = (0.0, 0.0),
    max_move_m: float = MAX_MOVE_M,
) -> Association:
    """Match ``seen`` detections to ``known`` mugs (which carry ids); see the module docstring for the rules.

    A matched detection keeps the position it was seen at, except a "known" one, which keeps its stored
    position (§4.1: its position information does not change). ``target_id`` names the mug the arm was
    handling; ``robot_xy`` is where "closest to the robot" is measured from.
    """
    ids = [k.mug_id for k in known]
    if any(not i for i in ids) or len(set(ids)) != len(ids):
        raise ValueError(f"known mugs need unique, non-empty ids, got {ids}")
    if target_id and target_id not in ids:
        raise ValueError(f"target_id {target_id!r} is not among the known mugs {sorted(ids)}")
    assigned: dict[int, Detection] = {}
    free_known = set(range(len(known)))
    free_seen = set(range(len(seen)))
    kept: list[str] = []
    moved: list[str] = []

    # 1. Mugs that have not moved: optimal one-to-one pairing among pairs within the tolerance.
    for ki, si in _assign(known, seen, free_known, free_seen, limit_m=known_within_m):
        k = known[ki]
        assigned[si] = replace(seen[si], mug_id=k.mug_id, x_m=k.x_m, y_m=k.y_m)
        if k.handle_seen and not seen[si].handle_seen:
            # It has not moved: where its handle was seen before still holds.
            assigned[si] = replace(assigned[si], handle_yaw_rad=k.handle_yaw_rad, handle_seen=True)
        kept.append(k.mug_id)
        free_known.discard(ki)
        free_seen.discard(si)

    # 2. The target: the unknown mug of its type closest to the robot (a lone unknown mug is the target).
    target = next((i for i in free_known if known[i].mug_id == target_id), None)
    if target is not None:
        same_type = [i for i in free_seen if seen[i].type == known[target].type]
        if same_type:
            si = min(
                same_type, key=lambda i: math.hypot(seen[i].x_m - robot_xy[0], seen[i].y_m - robot_xy[1])
            )
            assigned[si] = replace(seen[si], mug_id=target_id)
            moved.append(target_id)
            free_known.discard(target)
            free_seen.discard(si)

    # 3. The rest by an optimal assignment on distance, type for type.
    for ki, si in _assign(known, seen, free_known, free_seen, limit_m=max_move_m):
        assigned[si] = replace(seen[si], mug_id=known[ki].mug_id)
        moved.append(known[ki].mug_id)
        free_known.discard(ki)
        free_seen.discard(si)

    detections = tuple(assigned.get(i, replace(seen[i], mug_id="")) for i in range(len(seen)))
    return Association(
        detections=detections,
        kept=tuple(kept),
        moved=tuple(moved),
        lost=tuple(known[i].mug_id for i in sorted(free_known)),
        new=tuple(detections[i] for i in sorted(free_seen)),
    )


def _assign(
    known: Sequence[Detection],
    seen: Sequence[Detection],
    free_known: set[int],
    free_seen: set[int],
    *,
    limit_m: float,
) -> list[tuple[int, int]]:
    """Minimum-total-distance pairs of same-type mugs closer than ``limit_m`` (Hungarian method)."""
    ks, ss = sorted(free_known), sorted(free_seen)
    if not ks or not ss:
        return []
    cost = np.full((len(ks), len(ss)), np.inf)
    for a, ki in enumerate(ks):
        for b, si in enumerate(ss):
            if known[ki].type == seen[si].type:
                d = math.hypot(known[ki].x_m - seen[si].x_m, known[ki].y_m - seen[si].y_m)
                if d <= limit_m:
                    cost[a, b] = d
    if not np.isfinite(cost).any():
        return []
    # Forbidden pairs get a cost no allowed set of pairs can reach, and are dropped afterwards.
    big = 1.0 + float(np.nansum(np.where(np.isfinite(cost), cost, 0.0)))
    pairs = least_cost_assignment(np.where(np.isfinite(cost), cost, big).tolist())
    return [(ks[r], ss[c]) for r, c in pairs if np.isfinite(cost[r, c])]
