"""The job's state bounds, kept on the job's clock: each transition starts the watch of the state entered
(``progress.Progress`` says which bound it passes first, and when); when that moment comes the job faults,
naming the state and its bound. ``overdue`` is what the systemd watchdog asks meanwhile."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable

import structlog

from daemon.job.progress import Deadline, Progress
from daemon.job.services import Services

log = structlog.get_logger("daemon.job")


class Deadlines:
    """The watch over the current state's bound: ``entered`` on every transition, ``fault`` when it
    passes."""

    def __init__(
        self,
        services: Services,
        bound_of: Callable[[str], float | None],
        fault: Callable[[str], Awaitable[None]],
    ) -> None:
        self._services = services
        self._progress = Progress(bound_of)
        self._fault = fault
        self._task: asyncio.Task[None] | None = None  # faults the job when its state passes its bound

    def entered(self, source: str, dest: str, *, plan_time_limit_s: float) -> None:
        """The chart went from ``source`` to ``dest`` now: the last state's watch ends, the new one's
        starts (none for a state with no bound)."""
        self._progress.entered(source, dest, self._services.monotonic(), plan_time_limit_s=plan_time_limit_s)
        self.cancel()
        deadline = self._progress.deadline()
        if deadline is not None:
            self._task = asyncio.get_running_loop().create_task(
                self._fault_at(deadline), name=f"deadline:{deadline.state}"
            )

    def overdue(self) -> str | None:
        """Why the job is not making progress: its state has passed its time bound and the job has not left
        it yet (None: within its bound, or not working)."""
        deadline = self._progress.overdue(self._services.monotonic())
        return deadline.reason if deadline is not None else None

    def cancel(self) -> None:
        """End the current watch (the job is shutting down, or has left the state)."""
        if self._task is not None:
            self._task.cancel()
            self._task = None

    async def _fault_at(self, deadline: Deadline) -> None:
        await self._services.clock.sleep_until(deadline.at)
        with contextlib.suppress(Exception):  # a failing log call must not keep the fault from being sent
            log.error("state_stalled", state=deadline.state, bound_s=deadline.bound_s)
        await self._fault(deadline.reason)
