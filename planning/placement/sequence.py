"""Assignment and order checked with the arm (issue 24, item 3): which counter mug fills which planned slot
and in which order, every cycle planned by the cycle planner (its IK and its swept-volume check of the
gripper and the held mug along every trajectory) against the mugs placed before it and the mugs still on
the counter.

Two steps, both through the ``planning.interfaces.MotionPlanner`` seam (the placement planner itself never
loads the arm):

1. ``reach``: which counter mugs no cycle can take at all, before packing. Each mug is planned once to a
   probe slot (the tray's middle) with no other mug on the counter or the tray. A refusal before the cycle
   reaches the tray (grasp, lift, flip) in every alternative the planner tried, that no other mug caused,
   leaves the mug out: out of reach (a mug
   behind it is found by step 2, from where the arm will then stand). A mug whose probe fails over the
   tray only is kept (the slot is the problem, not the mug).
2. ``sequence``: the planned slots in an order the arm can build. Greedy over the placement's order (far
   edge first): the first slot whose cycle plans, with the mug the packer gave it or else (as the job's
   ``plan_for_slot`` does, and in its order) another counter mug of its type, is taken; its mug leaves the
   counter, stands on the tray with the handle where the cycle leaves it, and the arm starts the next
   cycle where this one ended. A slot refused by mugs still on the counter is tried again once one of them
   has moved; one refused by nothing movable (out of reach, the tray's walls, mugs on the tray, mugs that
   stay on the counter) is dropped for good. What is left when no slot plans is dropped, each with the mugs
   that blocked it: mugs the plan leaves on the counter, or mugs whose own slots are blocked in turn (no
   order frees them). A slot dropped because mugs this order placed before it are in the way may plan in
   another order: the refusal says it must come before their slots, and the greedy pass runs again with
   every precedence learned so far (a bounded search, ``REORDER_CHECKS``); the pass that builds the most
   is kept. The plan promises only the cycles it checked.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

from planning.interfaces import CyclePlan, MotionPlanner, MotionRefused, MugPose, StepKind, TraySlot

# A phase of the cycle over the tray: a refusal there, of the cycle or of one of its alternatives (the
# wrist turned or level for the regrasp and the place), says nothing about the mug's reach.
_TRAY_PHASE = re.compile(r"(^|: )place\.[a-z_]+: ")
# A short reason stops at this many characters (the recording has the full refusal).
_SHORT = 110
# The cycle checks the greedy passes after the first may spend looking for an order that builds more: about
# two more passes over a robot tray's slots on a crowded counter (a pass there plans 50-70 cycles; the cycle
# planner remembers the ones passes share).
REORDER_CHECKS = 100
# The target's coordinates in a refusal, which the short line already gives as the mug's.
_POINT = re.compile(r"\([-\d.]+, [-\d.]+, [-\d.]+\) m ")


@dataclass(frozen=True, slots=True)
class LeftOut:
    """A counter mug no cycle can take: ``reason`` is one short line, ``detail`` the planner's refusal."""

    mug_id: str
    reason: str
    detail: str


@dataclass(frozen=True, slots=True)
class Cycle:
    """One checked cycle: ``slot`` names the mug moved (``planned_for`` is the mug the packer gave the slot)
    and carries the handle's yaw the cycle leaves; ``plan`` is the cycle planned at that point."""

    slot: TraySlot
    planned_for: str
    plan: CyclePlan


@dataclass(frozen=True, slots=True)
class Sequenced:
    """The slots in the order the arm builds them, the slots dropped (the mug each named then, reason), how
    many cycles were planned to find out and how many orders (greedy passes) were tried."""

    cycles: tuple[Cycle, ...]
    dropped: tuple[tuple[str, str], ...]
    checks: int
    orders: int = 1


def reach(
    motion: MotionPlanner,
    start_q: Sequence[float],
    counter: Sequence[MugPose],
    probe: Callable[[MugPose], TraySlot],
) -> list[LeftOut]:
    """The counter mugs no cycle can take on their own (see the module): each planned from ``start_q`` to
    ``probe(mug)`` with nothing else on the counter or the tray. A refusal before the tray that no other mug
    caused leaves the mug out. In the order of ``counter``."""
    left: list[LeftOut] = []
    for mug in counter:
        try:
            motion.plan_cycle(start_q, mug, probe(mug), (), counter=())
        except MotionRefused as e:
            text = str(e)
            if _TRAY_PHASE.search(text) or e.blockers - {mug.mug_id}:
                continue
            left.append(LeftOut(mug.mug_id, _short_reason(mug, text), text))
    return left


def sequence(
    motion: MotionPlanner,
    start_q: Sequence[float],
    slots: Sequence[TraySlot],
    counter: Sequence[MugPose],
    on_tray: Sequence[TraySlot] = (),
    *,
    fixed: Sequence[MugPose] = (),
) -> Sequenced:
    """The slots (in the placement's order, each naming the mug planned for it) in an order whose every
    cycle plans (see the module). ``counter`` holds the mugs that may be moved (every one, planned or not,
    is an obstacle until it is moved), ``fixed`` mugs that stay on the counter (obstacles only),
    ``on_tray`` the mugs already placed.

    A slot the greedy pass drops because mugs it placed earlier are in the way might plan in another
    order: each such refusal says the slot must come before the slots of those mugs, and the greedy pass
    runs again keeping every precedence learned so far, until a pass learns nothing new or the passes
    after the first have spent ``REORDER_CHECKS`` cycle checks. The pass that builds the most wins (the
    first on a tie), so the search never builds fewer."""
    first = _greedy(motion, start_q, slots, counter, on_tray, fixed, {}, limit=None)
    best, last, checks, orders = first, first, first.checks, 1
    before: dict[str, frozenset[str]] = {}
    while len(best.cycles) < len(slots) and last.finished and checks - first.checks < REORDER_CHECKS:
        learned = _learn(before, last.order_blocked)
        if learned == before:
            break
        before = learned
        last = _greedy(
            motion,
            start_q,
            slots,
            counter,
            on_tray,
            fixed,
            before,
            limit=REORDER_CHECKS + first.checks - checks,
        )
        checks += last.checks
        orders += 1
        if last.finished and len(last.cycles) > len(best.cycles):
            best = last
    return Sequenced(best.cycles, best.dropped, checks, orders)


@dataclass(frozen=True, slots=True)
class _Pass:
    """One greedy pass: its cycles and drops, the cycles it planned, and for each slot it dropped because
    mugs it had placed were in the way, the slot and the slots of those mugs (planned-for ids);
    ``finished`` is false when the pass ran out of checks (its result is not used)."""

    cycles: tuple[Cycle, ...]
    dropped: tuple[tuple[str, str], ...]
    checks: int
    order_blocked: tuple[tuple[str, frozenset[str]], ...]
    finished: bool


def _greedy(
    motion: MotionPlanner,
    start_q: Sequence[float],
    slots: Sequence[TraySlot],
    counter: Sequence[MugPose],
    on_tray: Sequence[TraySlot],
    fixed: Sequence[MugPose],
    before: Mapping[str, frozenset[str]],
    *,
    limit: int | None,
) -> _Pass:
    """The greedy pass of the module, a slot tried only once the slots that must come ``before`` it (by
    planned-for id) are built or dropped, unless no other slot is left to try; it gives up (unfinished)
    once ``limit`` cycles are planned."""
    q = tuple(float(v) for v in start_q)
    remaining = [(s, s.mug_id) for s in slots]
    movable = {m.mug_id: m for m in counter}
    placed = list(on_tray)
    cycles: list[Cycle] = []
    dropped: list[tuple[str, str]] = []
    order_blocked: list[tuple[str, frozenset[str]]] = []
    waiting: dict[str, frozenset[str]] = {}  # planned-for id -> counter mugs that blocked its last try
    checks = [0]
    held_back = True
    while remaining:
        progress = False
        pending = {p for _, p in remaining}
        for i, (slot, planned_for) in enumerate(remaining):
            if limit is not None and checks[0] >= limit:
                return _Pass(tuple(cycles), tuple(dropped), checks[0], tuple(order_blocked), False)
            blockers = waiting.get(planned_for)
            if blockers is not None and blockers <= movable.keys():
                continue  # nothing that blocked it has moved since
            if held_back and before.get(planned_for, frozenset()) & pending:
                continue  # a slot that must come first is still to be built
            try:
                mug, plan = fill_slot(motion, q, slot, movable, placed, fixed, checks=checks)
            except MotionRefused as e:
                on_counter = e.blockers & movable.keys()
                if not on_counter:
                    dropped.append((slot.mug_id, str(e)))
                    by = {c.planned_for for c in cycles if c.slot.mug_id in e.blockers}
                    if by:
                        order_blocked.append((planned_for, frozenset(by)))
                    del remaining[i]
                    progress = True
                    break
                waiting[planned_for] = frozenset(on_counter)
                continue
            del remaining[i]
            waiting.pop(planned_for, None)
            if mug.mug_id != slot.mug_id:
                # The mug taken had a slot of its own (same type): the slot's planned mug takes it over.
                remaining = [
                    (replace(s, mug_id=slot.mug_id), p) if s.mug_id == mug.mug_id else (s, p)
                    for s, p in remaining
                ]
            done = replace(slot, mug_id=mug.mug_id, handle_yaw_rad=plan.handle_yaw_rad)
            cycles.append(Cycle(done, planned_for, plan))
            placed.append(done)
            del movable[mug.mug_id]
            q = _end_q(plan, q)
            progress = True
            break
        if progress:
            held_back = True
        elif held_back and before:
            held_back = False  # the slots held back are all that is left to try
        else:
            names = {slot.mug_id for slot, _ in remaining}
            for slot, planned_for in remaining:
                dropped.append(
                    (slot.mug_id, _stuck(slot.mug_id, waiting.get(planned_for, frozenset()), names))
                )
            break
    return _Pass(tuple(cycles), tuple(dropped), checks[0], tuple(order_blocked), True)


def _learn(
    before: Mapping[str, frozenset[str]], order_blocked: Sequence[tuple[str, frozenset[str]]]
) -> dict[str, frozenset[str]]:
    """``before`` with each slot refused by mugs placed earlier put before the slots of those mugs, unless
    that contradicts a precedence already kept (the slot of the mug in its way must come before it)."""
    out = dict(before)
    for slot, by in order_blocked:
        for other in sorted(by):
            if other not in _all_before(out, slot):
                out[other] = out.get(other, frozenset()) | {slot}
    return out


def _all_before(before: Mapping[str, frozenset[str]], slot: str) -> set[str]:
    """The slots that must come before ``slot``, directly or through others."""
    seen: set[str] = set()
    todo = list(before.get(slot, ()))
    while todo:
        s = todo.pop()
        if s not in seen:
            seen.add(s)
            todo.extend(before.get(s, ()))
    return seen


def _stuck(mug_id: str, blockers: frozenset[str], pending: set[str]) -> str:
    """Why a slot left when no slot plans is dropped: each counter mug that blocked its last try either has no
    slot in the plan (it stays on the counter) or waits for its own slot, blocked in turn (no order frees
    them: e.g. two mugs too close for the fingers to reach either). The slot's own mug is not named: it blocks
    only the other mugs of its type tried for the slot."""
    stay = sorted(blockers - pending)
    waits = sorted(blockers & pending - {mug_id})
    parts = []
    if stay:
        parts.append(f"{', '.join(stay)}, which the plan leaves on the counter")
    if waits:
        parts.append(f"{', '.join(waits)}, whose own slots are blocked in turn")
    return f"slot for {mug_id}: blocked by {' and by '.join(parts) or 'mugs that stay on the counter'}"


def fill_slot(
    motion: MotionPlanner,
    q: Sequence[float],
    slot: TraySlot,
    movable: Mapping[str, MugPose],
    placed: Sequence[TraySlot],
    fixed: Sequence[MugPose],
    *,
    checks: list[int] | None = None,
) -> tuple[MugPose, CyclePlan]:
    """The cycle filling ``slot``: its own mug, else the other movable mugs of its type nearest the arm
    first (``CyclePlanner.plan_for_slot``'s order, so the job repeats the choice); every other counter mug
    and the fixed ones (mugs given up, which stay where they are) are obstacles, never candidates. The job
    fills its slots with it when mugs given up stand on the counter (``daemon.job.cycles``). ``checks[0]``
    counts the cycles planned."""
    checks = [0] if checks is None else checks
    named = [m for m in movable.values() if m.mug_id == slot.mug_id]
    others = sorted(
        (m for m in movable.values() if m.type == slot.type and m.mug_id != slot.mug_id),
        key=lambda m: (math.hypot(m.x_m, m.y_m), m.mug_id),
    )
    reasons: list[MotionRefused] = []
    for mug in [*named, *others]:
        obstacles = tuple(m for m in movable.values() if m.mug_id != mug.mug_id) + tuple(fixed)
        checks[0] += 1
        try:
            plan = motion.plan_cycle(
                q, mug, replace(slot, mug_id=mug.mug_id), tuple(placed), counter=obstacles
            )
        except MotionRefused as e:
            # Straight from above the open gripper meets the mug itself: not a mug that has to move first.
            reasons.append(MotionRefused(str(e), blockers=e.blockers - {mug.mug_id}))
            continue
        return mug, plan
    if not reasons:
        raise MotionRefused(f"slot for {slot.mug_id}: no {slot.type} mug left on the counter")
    why = "; ".join(str(e) for e in reasons)
    raise MotionRefused.combining(f"slot for {slot.mug_id}: {why}", reasons)


def _end_q(plan: CyclePlan, q: tuple[float, ...]) -> tuple[float, ...]:
    """Where the arm stands when the cycle ends (its last move's last pose)."""
    moves = [s.trajectory for s in plan.steps if s.kind is StepKind.MOVE and s.trajectory is not None]
    if not moves:
        return q
    return tuple(float(v) for v in moves[-1].positions[-1])


def _short_reason(mug: MugPose, refusal: str) -> str:
    """``m3 at (0.081, 0.356) m: side_grasp.approach: (0.081, 0.356, 0.060) m unreachable: no solution
    within the joint limits...`` (one short line: the first reason of the refusal)."""
    where = f"{mug.mug_id} at ({mug.x_m:.3f}, {mug.y_m:.3f}) m"
    first = _POINT.sub("", refusal.split("; ")[0])
    text = f"{where}: {first}"
    return text if len(text) <= _SHORT else text[: _SHORT - 3] + "..."
