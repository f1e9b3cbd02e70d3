"""What the job's units work with: the backend's devices and planners, the configuration, the publisher, the
association and the planning process, plus the job's only reads of time.

The runner builds one ``Services`` and hands it to every unit of work; units never reach the runner itself.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import msgspec

from daemon.backend import Backend
from daemon.config import Config
from drivers.interfaces import Clock
from perception.interfaces import Associate
from planning.placement import PlacementPlanner, PlanOptions, PlanResult, Problem
from wire.messages import UNSET, JobEvent, Payload

Publish = Callable[[str, Payload], None]

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Services:
    """The job's means, shared by its units. ``backend`` is mutable: a new simulated counter may bring a
    new tray and the motion planner for it."""

    backend: Backend
    config: Config
    publish: Publish
    associate: Associate
    state: Callable[[], str]  # the chart's current leaf, for event payloads
    # A process pool for placement planning (its CPU time must not hold the GIL against the event loop);
    # None: a thread.
    executor: concurrent.futures.Executor | None = None

    def event(self, event: JobEvent) -> None:
        """Publish one job event on ``events``: its kind, the chart's state (unless the event names one),
        the wall clock, the session's monotonic time and the kind's detail."""
        state = self.state() if event.state is UNSET else event.state
        stamped = msgspec.structs.replace(event, state=state, t=self.wall_time(), t_device=self.monotonic())
        self.publish("events", stamped)

    def transition(self, **detail: Any) -> None:
        """Publish a ``transition`` on ``events``: its detail is the trigger, the states and the firing
        unit's guard values, in the order the unit gives them (open: no kind struct writes it)."""
        self.publish(
            "events",
            {
                "kind": "transition",
                "state": self.state(),
                "t": self.wall_time(),
                "t_device": self.monotonic(),
                **detail,
            },
        )

    async def plan_placement(
        self, planner: PlacementPlanner, problem: Problem, options: PlanOptions
    ) -> PlanResult:
        """Run placement planning off the event loop: in the planning process when there is one, or as the
        backend says (a replay serves the recorded plans)."""
        if self.backend.placement is not None:
            return await self.backend.placement(planner, problem, options, self._plan_off_loop)
        return await self._plan_off_loop(planner, problem, options)

    async def _plan_off_loop(
        self, planner: PlacementPlanner, problem: Problem, options: PlanOptions
    ) -> PlanResult:
        if self.executor is None:
            return await asyncio.to_thread(planner, problem, options)
        return await asyncio.get_running_loop().run_in_executor(self.executor, planner, problem, options)

    # The job's reads of time, all of them, on the backend's clock (the wall clock on the robot, simulated
    # time in simulation): ``now`` for payloads, the monotonic clock for durations and deadlines, the waits.

    @property
    def clock(self) -> Clock:
        return self.backend.clock

    def wall_time(self) -> float:
        return self.backend.clock.now()

    def monotonic(self) -> float:
        return self.backend.clock.monotonic()

    async def sleep(self, seconds: float) -> None:
        await self.backend.clock.sleep(seconds)

    async def wait_done(self, task: asyncio.Task[T], timeout_s: float | None) -> None:
        """Wait until ``task`` is done or ``timeout_s`` has passed (None: no limit)."""
        await self.backend.clock.wait(task, timeout_s)
