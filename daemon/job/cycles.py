"""Motion planning of the next cycle: which queued slot is filled next, with which mug, and its
pick-flip-place plan (``MotionPlanner.plan_for_slot``), or a lost mug's new plan (``plan_cycle``).

The chart decides ``has_next_mug`` when it leaves ``detect`` (after each mug) or ``plan`` (after a new
placement), so both end by taking the next cycle: a slot no motion reaches is not a next mug.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Mapping
from dataclasses import replace

from daemon.job.context import Deferral, JobContext
from daemon.job.counter import GIVE_UP_WRITES, give_up, tray_obstacles
from daemon.job.services import Services
from planning.interfaces import CyclePlan, MotionRefused, MugPose, TraySlot
from planning.placement import TrayMug
from planning.placement.sequence import fill_slot
from statechart.chart import CYCLE_PHASES
from wire.messages import CyclePlannedEvent, MotionRefusedEvent, MugSwappedEvent

# The context keys these touch, for the declarations of the units that call them.
_ADOPT_WRITES = frozenset({"current", "cycle", "step", "grasp_held"})
NEXT_CYCLE_READS = frozenset({"counter", "on_tray", "strays", "given_up"})
NEXT_CYCLE_WRITES = frozenset({"queue", "deferred", "current_tray_mug"}) | _ADOPT_WRITES | GIVE_UP_WRITES
RETRY_READS = frozenset({"counter", "on_tray", "strays"})
RETRY_WRITES = _ADOPT_WRITES


async def take_next_cycle(services: Services, ctx: JobContext) -> bool:
    """Make the next queued slot whose cycle can be planned the current one; False when none can.

    When the slot's own mug is blocked, the planner may fill it with another counter mug of its type, and
    the two swap slots. A slot no motion reaches keeps its place in the queue and is planned again once
    what blocked it changed (``Deferral``): taking the next mug off the counter may clear its way. The
    queued mugs are given up only when no queued slot can be planned."""
    i = 0
    while i < len(ctx.queue):
        slot, tray_mug = ctx.queue[i]
        if slot.mug_id not in ctx.counter or slot.mug_id in ctx.given_up:
            del ctx.queue[i]
            continue
        available = {k: m for k, m in ctx.counter.items() if k not in ctx.given_up}
        deferral = ctx.deferred.get(slot)
        if deferral is not None and deferral.still_blocked(available, slot):
            i += 1
            continue
        del ctx.queue[i]
        if await _fill(services, ctx, slot, tray_mug, available):
            return True
        ctx.queue.insert(i, (slot, tray_mug))
        i += 1
    for slot, _ in ctx.queue:
        if slot.mug_id in ctx.counter and slot.mug_id not in ctx.given_up:
            give_up(services, ctx, slot.mug_id, "no motion reaches it")
    ctx.queue = []
    ctx.current = None
    ctx.cycle = None
    return False


async def plan_retry(services: Services, ctx: JobContext, mug: MugPose, slot: TraySlot) -> bool:
    """Plan the current slot's cycle again for its mug where it now lies (after a failed grasp or a drop)
    and make it current; False when no motion reaches it."""
    js = await services.backend.arm.read_joints()
    others = tuple(m for m in ctx.counter.values() if m.mug_id != mug.mug_id)
    try:
        cycle = await asyncio.to_thread(
            functools.partial(services.backend.motion.plan_cycle, counter=others),
            js.position_rad,
            mug,
            slot,
            tray_obstacles(ctx),
        )
    except MotionRefused as e:
        services.event(MotionRefusedEvent(mug_id=mug.mug_id, reason=str(e)))
        return False
    _adopt(services, ctx, mug, slot, cycle, retry=True)
    return True


async def _fill(
    services: Services,
    ctx: JobContext,
    slot: TraySlot,
    tray_mug: TrayMug,
    available: Mapping[str, MugPose],
) -> bool:
    """Plan the cycle filling ``slot`` with its mug or, when that one is blocked, with the nearest reachable
    counter mug of the same type; the two mugs swap their places in the plan. Mugs given up are obstacles
    (``sequence.fill_slot``, the plan check's own choice, when any stands on the counter)."""
    js = await services.backend.arm.read_joints()
    motion = services.backend.motion
    # Mugs given up stay where they are: obstacles for every later cycle, never candidates for a slot.
    fixed = tuple(m for k, m in ctx.counter.items() if k in ctx.given_up)
    try:
        if fixed:
            mug, cycle = await asyncio.to_thread(
                fill_slot, motion, js.position_rad, slot, available, tray_obstacles(ctx), fixed
            )
        else:  # the planner's own call (it decides once per slot what no candidate can change)
            mug, cycle = await asyncio.to_thread(
                motion.plan_for_slot, js.position_rad, slot, tuple(available.values()), tray_obstacles(ctx)
            )
    except MotionRefused as e:
        ctx.deferred[slot] = Deferral.of(e.blockers, available, slot)
        services.event(MotionRefusedEvent(mug_id=slot.mug_id, reason=str(e)))
        return False
    ctx.deferred.pop(slot, None)
    if mug.mug_id != slot.mug_id:
        # The swapped-in mug's own slot (same type, so the same footprint) goes to the blocked mug.
        ctx.queue = [
            (replace(s, mug_id=slot.mug_id), replace(t, id=slot.mug_id)) if s.mug_id == mug.mug_id else (s, t)
            for s, t in ctx.queue
        ]
        services.event(
            MugSwappedEvent(slot_for=slot.mug_id, mug_id=mug.mug_id, reason="blocked or out of reach")
        )
        slot = replace(slot, mug_id=mug.mug_id)
        tray_mug = replace(tray_mug, id=mug.mug_id)
    ctx.current_tray_mug = tray_mug
    _adopt(services, ctx, mug, slot, cycle, retry=False)
    return True


def _adopt(
    services: Services, ctx: JobContext, mug: MugPose, slot: TraySlot, cycle: CyclePlan, *, retry: bool
) -> None:
    """Make ``cycle`` (taking ``mug`` to ``slot``) the current one, from its first step."""
    bad = [s.phase for s in cycle.steps if s.phase not in CYCLE_PHASES]
    if bad:
        raise MotionRefused(f"cycle plan for {mug.mug_id} has steps for unknown phases {sorted(set(bad))}")
    ctx.current = slot
    ctx.cycle = cycle
    ctx.step = 0
    ctx.grasp_held = False
    services.event(
        CyclePlannedEvent(
            mug_id=mug.mug_id,
            retry=retry,
            duration_s=round(cycle.duration_s, 3),
            energy_j=round(cycle.energy_j, 3),
        )
    )
