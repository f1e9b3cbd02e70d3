"""A placement the arm can build (issue 24, item 3): ``plan_with_arm`` leaves out the counter mugs no cycle
can take (``sequence.reach``), packs the rest with the chosen method and footprint, then checks the
assignment and the order cycle by cycle with the cycle planner (``sequence.sequence``). The result lists
only the checked cycles, in the order they were checked; when slots had to be dropped, the mugs planned for
them are left out and the tray is packed once more (mug-shaped footprints: first a round with rectangles and
the same mugs), and the round that builds more wins. What the plan says of each reachable mug it leaves on
the counter speaks of that round: its own dropped slots, an earlier round's drop that kept the mug out of its
packing (named as that round's), or no slot in its packing.

Only ``planning.interfaces`` is needed from the arm's side: the caller passes its ``MotionPlanner`` (the
daemon's, possibly in another process; a bench's ``CyclePlanner``).
"""

from __future__ import annotations

import asyncio
import functools
import re
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol, TypeVar

from planning.interfaces import MotionPlanner, MugPose, TraySlot
from planning.placement.context import PlanOptions
from planning.placement.cost import Evaluator
from planning.placement.planner import PlacedMug, PlanResult, plan
from planning.placement.problem import Problem
from planning.placement.seam import PlacementPlanner
from planning.placement.sequence import LeftOut, Sequenced, reach, sequence

# Packing rounds at most: the first, and one more without the mugs of the slots the first had to drop (with
# mug-shaped footprints a rectangle round comes between them, see ``plan_checked``).
ROUNDS = 2

_T = TypeVar("_T")
# How the notes of a checked plan start.
_CHECKED = "checked with the arm: "
_DROPPED = "slot dropped: "
# How a reason from an earlier packing round names that round's packing.
_KIND = {"mug": "mug-shaped packing", "rect": "rectangle packing"}
# A refusal that says the arm cannot get there (IK, joint limits, beyond the side-grasp ring).
_REACH = re.compile(r"unreachable|out of reach")


@dataclass(frozen=True, slots=True)
class CheckedPlan:
    """``result``: the placement as the arm will build it (only checked cycles, ``order`` the checked order,
    ids as the cycles move them); ``left_out``: the counter mugs out of reach before packing; ``sequenced``:
    the winning round's cycles and what it dropped; ``planned``: how many the packer placed in that round."""

    result: PlanResult
    left_out: tuple[LeftOut, ...]
    sequenced: Sequenced
    planned: int
    rounds: int
    # (mug id, why) of every mug whose slot was dropped and which the result leaves on the counter, in words
    # about this plan (see ``_left_on_counter``).
    dropped: tuple[tuple[str, str], ...] = ()
    # The mugs the kept round's packing gave no slot (the tray held no more of them).
    unpacked: tuple[str, ...] = ()

    def summary_lines(self) -> list[str]:
        """One short line per counter mug left out before packing (out of reach, or no cycle takes it for
        another reason, e.g. its flip would hit the tray's wall), then one per slot dropped."""
        lines = [
            f"{'out of reach' if _REACH.search(m.detail) else 'no cycle takes it'}: {m.reason}"
            for m in self.left_out
        ]
        lines += [f"slot dropped: {mug}: {_first_line(why)}" for mug, why in self.dropped]
        if self.unpacked:
            lines.append(
                f"not packed: {', '.join(self.unpacked)}: the packing kept fits {self.planned} of its"
                f" {self.planned + len(self.unpacked)} mugs on the tray"
            )
        return lines


class OffLoop(Protocol):
    """Runs a blocking call somewhere the caller's event loop is not blocked (``asyncio.to_thread``)."""

    def __call__(self, fn: Callable[[], _T], /) -> Awaitable[_T]: ...


async def plan_checked(
    problem: Problem,
    options: PlanOptions,
    motion: MotionPlanner,
    start_q: Sequence[float],
    counter: Sequence[MugPose],
    *,
    pack: Callable[[Problem, PlanOptions], Awaitable[PlanResult]],
    off_loop: OffLoop,
    fixed: Sequence[MugPose] = (),
    on_tray: Sequence[TraySlot] = (),
) -> CheckedPlan:
    """Plan ``problem`` (its counter mugs are ``counter``, same ids; ``fixed`` mugs stay on the counter as
    obstacles; ``on_tray`` the placed mugs as the arm sees them) so that every planned cycle is checked.
    ``pack`` packs a problem (the daemon's planning process); the cycle planner's calls, which block, go
    through ``off_loop``, one batch at a time, never while ``pack`` runs."""
    started = time.perf_counter()
    poses = {m.mug_id: m for m in counter}
    missing = [m.id for m in problem.mugs if m.id not in poses]
    if missing:
        raise ValueError(f"counter mugs without a pose: {', '.join(missing)}")
    cx, cy = problem.to_world_mm(problem.tray_size_mm[0] / 2.0, problem.tray_size_mm[1] / 2.0)

    def probe(mug: MugPose) -> TraySlot:
        return TraySlot(mug.mug_id, mug.type, cx / 1000.0, cy / 1000.0)

    movable = [poses[m.id] for m in problem.mugs]
    left = tuple(await off_loop(functools.partial(reach, motion, start_q, movable, probe)))
    gone = {m.mug_id for m in left}
    stays = (*fixed, *(poses[m] for m in sorted(gone)))
    pickable = [m for m in movable if m.mug_id not in gone]
    tried: list[_Round] = []
    excluded = set(gone)
    # A mug-shaped round that dropped slots is followed by one with the thesis's rectangles and the same
    # mugs: their footprints leave the gripper more room around the mugs on the tray (a replan after a mug
    # came to the counter dropped its only slot, which the rectangle layout had room for).
    rect_next = False
    limit = ROUNDS + 1 if problem.footprint_kind == "mug" else ROUNDS
    while len(tried) < limit:
        packed = replace(problem, mugs=tuple(m for m in problem.mugs if m.id not in excluded))
        if rect_next:
            packed = replace(packed, footprint_kind="rect")
        result = await pack(packed, options)
        slots = result.slots(packed)
        checked = await off_loop(
            functools.partial(sequence, motion, start_q, slots, pickable, on_tray, fixed=stays)
        )
        # A plan checked before (a replay's recorded one) lists in its notes the slots its check dropped.
        why = (*_dropped_notes(result.notes), *checked.dropped)
        tried.append(_Round(len(tried) + 1, packed, result, checked, why))
        if not checked.dropped or not packed.mugs:
            break
        rect_next = problem.footprint_kind == "mug" and len(tried) == 1
        if not rect_next:
            excluded |= {mug for mug, _ in checked.dropped}
    kept = max(tried, key=lambda r: len(r.checked.cycles))  # the first of those that build the most
    reachable = replace(problem, mugs=tuple(m for m in problem.mugs if m.id not in gone))
    still, unpacked = _left_on_counter(kept, tried)
    wall_s = time.perf_counter() - started
    built = _as_built(reachable, options, kept.result, kept.checked, wall_s, left, still)
    return CheckedPlan(built, left, kept.checked, kept.result.n, len(tried), still, unpacked)


@dataclass(frozen=True, slots=True)
class _Round:
    """One packing round: its number (from 1), the problem packed (the mugs left in, the footprint), the
    packing, its check, and (mug id, why) of every slot dropped in it."""

    number: int
    packed: Problem
    result: PlanResult
    checked: Sequenced
    dropped: tuple[tuple[str, str], ...]


def _left_on_counter(
    kept: _Round, tried: Sequence[_Round]
) -> tuple[tuple[tuple[str, str], ...], tuple[str, ...]]:
    """Why the plan of the ``kept`` round leaves each reachable mug on the counter, in words about that plan:
    a slot the round dropped, with its own reason; a mug an earlier round's dropped slot kept out of this
    round's packing, with that reason named as that round's (it speaks of that round's plan); and the mugs
    the round packed no slot for (returned apart, by id)."""
    placed = {c.slot.mug_id for c in kept.checked.cycles}
    why: dict[str, str] = {}
    for mug, reason in kept.dropped:
        if mug not in placed:
            why.setdefault(mug, reason)
    packed = {m.id for m in kept.packed.mugs}
    for earlier in reversed(tried[: kept.number - 1]):
        kind = _KIND[earlier.packed.footprint_kind]
        for mug, reason in earlier.dropped:
            if mug not in packed and mug not in placed:
                why.setdefault(mug, f"in round {earlier.number} ({kind}): {reason}")
    unpacked = tuple(m.id for m in kept.packed.mugs if m.id not in placed and m.id not in why)
    return tuple(why.items()), unpacked


def _dropped_notes(notes: Sequence[str]) -> list[tuple[str, str]]:
    """The (mug id, why) a checked plan's notes list as dropped (``_as_built`` writes them)."""
    out = []
    for n in notes:
        if n.startswith(_DROPPED):
            mug, _, why = n.removeprefix(_DROPPED).partition(": ")
            out.append((mug, why))
    return out


def plan_with_arm(
    problem: Problem,
    options: PlanOptions,
    motion: MotionPlanner,
    start_q: Sequence[float],
    counter: Sequence[MugPose],
    *,
    fixed: Sequence[MugPose] = (),
    on_tray: Sequence[TraySlot] = (),
    planner: PlacementPlanner = plan,
) -> CheckedPlan:
    """``plan_checked`` in this thread, packing with ``planner`` (benches, tests, ``dishbot plan``)."""

    async def pack(p: Problem, o: PlanOptions) -> PlanResult:
        return planner(p, o)

    return asyncio.run(
        plan_checked(
            problem,
            options,
            motion,
            start_q,
            counter,
            pack=pack,
            off_loop=_here,
            fixed=fixed,
            on_tray=on_tray,
        )
    )


async def _here(fn: Callable[[], _T], /) -> _T:
    return fn()


def _as_built(
    problem: Problem,
    options: PlanOptions,
    result: PlanResult,
    checked: Sequenced,
    wall_s: float,
    left: Sequence[LeftOut],
    dropped: Sequence[tuple[str, str]],
) -> PlanResult:
    """``result`` reduced to the checked cycles in their order, its parameters recomputed; ``unplaced``
    lists the mugs of ``problem`` (the counter's reachable mugs: those packed in the first round, as a
    replay's planner is asked for them) not placed. The notes say how the check went and list the slots
    dropped (``slot dropped: <mug>: <why>``), so that a replay served this plan says the same."""
    spots = {p.id: p for p in result.placed}
    index = {m.id: i for i, m in enumerate(problem.mugs)}
    placed: list[PlacedMug] = []
    for k, c in enumerate(checked.cycles, start=1):
        p = spots[c.planned_for]
        yaw = c.plan.handle_yaw_rad if c.plan.handle_yaw_rad is not None else p.handle_yaw_rad
        placed.append(replace(p, id=c.slot.mug_id, order=k, handle_yaw_rad=yaw))
    layout = [(index[p.id], p.x_mm, p.y_mm, p.rotated) for p in placed]
    metrics = Evaluator(problem, options.move_cost).metrics_of_layout(layout)
    ids = {p.id for p in placed}
    note = (
        f"{_CHECKED}{len(placed)} of {result.n} planned cycles plan in this order"
        f" ({checked.checks} cycles planned{_orders_tried(checked)}), {len(left)} counter mugs out of reach"
        " left out before packing"
    )
    return replace(
        result,
        wall_time_s=wall_s,
        placed=tuple(placed),
        unplaced=tuple(m.id for m in problem.mugs if m.id not in ids),
        n=metrics.n,
        A_mm2=metrics.A,
        E_j=metrics.E,
        t_s=wall_s + metrics.t,
        s=metrics.s,
        optimal=result.optimal if metrics.n == result.n else False,
        notes=(
            *(n for n in result.notes if not n.startswith((_DROPPED, _CHECKED))),
            note,
            *(f"{_DROPPED}{mug}: {why}" for mug, why in dropped),
        ),
    )


def _orders_tried(checked: Sequenced) -> str:
    """``, 2 orders tried`` when the check searched for another order (nothing when the first one stood)."""
    return f", {checked.orders} orders tried" if checked.orders > 1 else ""


def _first_line(text: str, limit: int = 110) -> str:
    first = text.split("; ")[0]
    return first if len(first) <= limit else first[: limit - 3] + "..."
