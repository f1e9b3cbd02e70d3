"""``plan``: placement planning of the counter's mugs around those already on the tray (a
``planning.placement.PlacementPlanner``), checked with the arm (``planning.placement.checked``: counter
mugs no cycle can take are left out before packing, and every slot's cycle is planned in the order the job
will run them, against the mugs placed before it and those still on the counter; mugs given up stay
obstacles), published on ``plan``; then the first cycle is taken (``cycles.take_next_cycle``)."""

from __future__ import annotations

import asyncio
import functools

from daemon.config import Config
from daemon.job.context import JobContext, Outcome
from daemon.job.counter import tray_obstacles
from daemon.job.cycles import NEXT_CYCLE_READS, NEXT_CYCLE_WRITES, take_next_cycle
from daemon.job.services import Services
from daemon.job.unit import Unit
from daemon.messages import plan_message
from daemon.planners import CyclePlannerSpec, plan_placement, set_down
from description.cell import Tray
from planning.interfaces import TraySlot
from planning.placement import (
    CounterMug,
    InvalidProblem,
    MugType,
    PlacementPlanner,
    PlanOptions,
    PlanResult,
    Problem,
    TrayMug,
    TrayStray,
    plan,
)
from planning.placement.checked import CheckedPlan, plan_checked
from wire.messages import OutOfReach, OutOfReachEvent, Slot, SlotDroppedEvent, WarningEvent


class Plan(Unit):
    """Plan the tray slots and their order; ``planned`` with ``has_next_mug``."""

    reads = NEXT_CYCLE_READS | {"planner", "tray_mugs", "given_up", "on_tray", "strays", "counter"}
    writes = NEXT_CYCLE_WRITES | {"queue", "needs_plan", "summary"}

    def __init__(self) -> None:
        super().__init__("plan", ("planned",))

    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        ctx.queue = []
        ctx.needs_plan = False
        try:
            problem = problem_of(services, ctx)
            checked = await checked_plan(services, ctx, problem)
        except InvalidProblem as e:
            services.event(WarningEvent(message=f"placement planning refused the problem: {e}"))
            return Outcome("planned", {"has_next_mug": False})
        result = checked.result
        ctx.queue = _slots(result, problem, ctx)
        ctx.summary.planned = len(ctx.on_tray) + len(ctx.queue)
        ctx.summary.left_out = checked.summary_lines()
        for m in checked.left_out:
            services.event(OutOfReachEvent(mug_id=m.mug_id, reason=m.reason, detail=m.detail))
        for mug_id, why in checked.dropped:
            services.event(SlotDroppedEvent(mug_id=mug_id, reason=why))
        out_of_reach = [OutOfReach(id=m.mug_id, reason=m.reason) for m in checked.left_out]
        slots = [
            Slot(id=s.mug_id, type=s.type, x_m=round(s.x_m, 5), y_m=round(s.y_m, 5), rotated=s.rotated)
            for s, _ in ctx.queue
        ]
        t = services.wall_time()
        services.publish("plan", plan_message(result, out_of_reach=out_of_reach, slots=slots, t=t))
        return Outcome("planned", {"has_next_mug": await take_next_cycle(services, ctx)})


async def checked_plan(services: Services, ctx: JobContext, problem: Problem) -> CheckedPlan:
    """``problem`` planned and checked with the arm from where it stands (``plan_checked``): the packing
    goes through ``Services.plan_placement`` (the planning process; a replay's recorded plans), the cycle
    planner's calls, which block, run in a thread."""
    planner = placement_planner(services.config, services.backend.tray)

    async def pack(p: Problem, options: PlanOptions) -> PlanResult:
        return await services.plan_placement(planner, p, options)

    js = await services.backend.arm.read_joints()
    return await plan_checked(
        problem,
        ctx.planner,
        services.backend.motion,
        tuple(js.position_rad),
        [m for m in ctx.counter.values() if m.mug_id not in ctx.given_up],
        pack=pack,
        off_loop=asyncio.to_thread,
        fixed=[m for m in ctx.counter.values() if m.mug_id in ctx.given_up],
        on_tray=tray_obstacles(ctx),
    )


def placement_planner(config: Config, tray: Tray) -> PlacementPlanner:
    """``planning.placement.plan``; with ``planner.energy_model = "dynamics"``, move costs from the arm's
    dynamics in this cell (built once per planning process)."""
    if config.planner.energy_model != "dynamics":
        return plan
    return functools.partial(
        plan_placement,
        dynamics=CyclePlannerSpec(config.cell, tray, config.mug_types, set_down=set_down(config)),
    )


def problem_of(services: Services, ctx: JobContext) -> Problem:
    """The placement problem of the counter's mugs (those given up left out) around the mugs on the tray
    (those the job placed, and the strays where they lie)."""
    tray = services.backend.tray
    config = services.config
    types = {
        m.name: MugType(m.name, m.diameter_mm, m.width_mm, m.height_mm, m.mass_kg) for m in config.mug_types
    }
    mugs = tuple(
        CounterMug(
            m.mug_id, m.type, m.x_m * 1000.0, m.y_m * 1000.0, m.handle_yaw_rad if m.handle_seen else None
        )
        for m in ctx.counter.values()
        if m.mug_id not in ctx.given_up
    )
    return Problem(
        tray_size_mm=tray.size_mm,
        tray_origin_mm=(tray.origin_m[0] * 1000.0, tray.origin_m[1] * 1000.0),
        mugs=mugs,
        mug_types=types,
        placed=tuple(ctx.tray_mugs),
        tolerance_mm=config.planner.tolerance_mm,
        allow_rotation=config.planner.allow_rotation,
        footprint_kind=config.planner.footprint,
        strays=tuple(
            TrayStray(
                m.mug_id, m.type, tray.to_tray_mm(m.x_m, m.y_m), m.handle_yaw_rad if m.handle_seen else None
            )
            for m in ctx.strays
        ),
    )


def _slots(result: PlanResult, problem: Problem, ctx: JobContext) -> list[tuple[TraySlot, TrayMug]]:
    """The planned slots in placing order (world frame for the arm, tray frame for the next placement)."""
    queue = []
    for placed in sorted(result.placed, key=lambda p: p.order):
        if placed.id not in ctx.counter or placed.id in ctx.given_up:
            continue
        bx, by = problem.brim_centre_on_tray(placed.type, placed.x_mm, placed.y_mm)
        wx, wy = problem.to_world_mm(bx, by)
        slot = TraySlot(placed.id, placed.type, wx / 1000.0, wy / 1000.0, placed.rotated)
        tray_mug = TrayMug(
            placed.id, placed.type, placed.x_mm, placed.y_mm, placed.rotated, placed.handle_yaw_rad
        )
        queue.append((slot, tray_mug))
    return queue
