"""``detect``: look at the counter after the start and after each mug; replan when a mug came or went, else
take the next planned mug (``cycles.take_next_cycle``)."""

from __future__ import annotations

from daemon.job.context import JobContext, Outcome
from daemon.job.counter import LOOK_READS, LOOK_WRITES, look
from daemon.job.cycles import NEXT_CYCLE_READS, NEXT_CYCLE_WRITES, take_next_cycle
from daemon.job.services import Services
from daemon.job.unit import Unit
from wire.messages import CounterChangedEvent


class Detect(Unit):
    """Observe and associate; ``detected`` with ``needs_plan`` (the counter changed, or nothing is planned
    yet) or ``has_next_mug`` (a queued slot's cycle could be planned)."""

    reads = LOOK_READS | NEXT_CYCLE_READS | {"given_up", "on_tray"}
    writes = LOOK_WRITES | NEXT_CYCLE_WRITES | {"counter", "needs_plan", "summary"}

    def __init__(self) -> None:
        super().__init__("detect", ("detected",))

    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        previous = set(ctx.counter) - ctx.given_up
        ctx.counter = await look(services, ctx)
        came = set(ctx.counter) - ctx.given_up - previous
        went = previous - set(ctx.counter)
        if previous and (came or went):
            services.event(CounterChangedEvent(came=sorted(came), went=sorted(went)))
        ctx.needs_plan = ctx.needs_plan or bool(came or went)
        ctx.summary.detected = max(ctx.summary.detected, len(ctx.counter) + len(ctx.on_tray))
        if ctx.needs_plan:
            return Outcome("detected", {"needs_plan": True, "has_next_mug": False})
        has_next = await take_next_cycle(services, ctx)
        return Outcome("detected", {"needs_plan": False, "has_next_mug": has_next})
