"""``recover_lost_mug`` (thesis §4.3.1): after a grasp that did not hold or a mug dropped on the way, open,
look again, and grasp the mug where it now lies, or leave it after ``grasp.max_attempts`` and replan."""

from __future__ import annotations

from daemon.job.context import JobContext, Outcome
from daemon.job.counter import GIVE_UP_WRITES, LOOK_READS, LOOK_WRITES, give_up, look
from daemon.job.cycles import RETRY_READS, RETRY_WRITES, plan_retry
from daemon.job.manipulation import gripper_action
from daemon.job.services import Services
from daemon.job.unit import Unit
from wire.messages import MugFoundEvent


class RecoverLostMug(Unit):
    """``recovered`` with ``mug_found`` (its cycle is planned again from where it lies), or without it (the
    rest is replanned)."""

    reads = LOOK_READS | RETRY_READS | {"current"}
    writes = LOOK_WRITES | RETRY_WRITES | GIVE_UP_WRITES | {"counter", "carrying", "attempts", "needs_plan"}

    def __init__(self) -> None:
        super().__init__("recover_lost_mug", ("recovered",))

    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        current = ctx.current
        ctx.carrying = False
        await gripper_action(services, services.backend.gripper.open())
        target = current.mug_id if current is not None and current.mug_id in ctx.counter else ""
        ctx.counter = await look(services, ctx, target_id=target)
        if current is None:
            ctx.needs_plan = True
            return Outcome("recovered", {"mug_found": False})
        mug = ctx.counter.get(current.mug_id)
        attempts = ctx.attempts.get(current.mug_id, 0) + 1
        ctx.attempts[current.mug_id] = attempts
        if (
            mug is not None
            and attempts < services.config.grasp.max_attempts
            and await plan_retry(services, ctx, mug, current)
        ):
            services.event(MugFoundEvent(mug_id=current.mug_id, x_m=mug.x_m, y_m=mug.y_m))
            return Outcome("recovered", {"mug_found": True})
        if any(m.mug_id == current.mug_id for m in ctx.strays):
            reason = "fell on the tray; left there as an obstacle"
        elif mug is None:
            reason = "not seen on the counter"
        else:
            reason = f"given up after {attempts} attempts"
        give_up(services, ctx, current.mug_id, reason)
        ctx.current = None
        ctx.cycle = None
        ctx.needs_plan = True
        return Outcome("recovered", {"mug_found": False})
