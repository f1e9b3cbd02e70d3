"""The job's commands (start, pause, stop, fault, estop, resume, reset): what each does to the devices, the
job's context and the chart.

The runner's control task takes one command at a time from its inbox and hands it here; a command acts on
the chart only through the runner (``Control``), so every transition is still fired from that one task.
"""

from __future__ import annotations

import asyncio
import contextlib
from dataclasses import dataclass
from typing import Protocol

import structlog

from daemon.job.context import JobContext, Outcome
from daemon.job.devices import DeviceSupervisor
from daemon.job.errors import CommandRefused
from daemon.job.requests import StartRequest
from daemon.job.services import Services
from statechart.machine import StateChart
from wire.messages import SceneSetEvent

log = structlog.get_logger("daemon.job")


@dataclass(slots=True)
class Command:
    """A command waiting in the runner's inbox: its verb, a start's request, a fault's reason, the reply."""

    verb: str
    request: StartRequest | None
    reason: str
    reply: asyncio.Future[dict[str, object]]


class Control(Protocol):
    """What a command may ask of the runner."""

    @property
    def chart(self) -> StateChart: ...

    @property
    def context(self) -> JobContext: ...

    def begin(self, ctx: JobContext) -> None:
        """A new job starts with ``ctx``."""

    async def cancel_work(self) -> None:
        """Cancel the current state's unit of work and wait for it."""

    async def fire(self, outcome: Outcome) -> None:
        """Fire ``outcome`` on the chart and start the new state's work."""

    async def advance(self, outcome: Outcome) -> None:
        """``fire``, reporting a fault (and stopping the arm) first when it is one."""


class Commands:
    """Carries out the job's commands; ``CommandRefused`` when one cannot be taken now."""

    def __init__(self, services: Services, devices: DeviceSupervisor, control: Control) -> None:
        self._services = services
        self._devices = devices
        self._control = control

    async def execute(self, cmd: Command) -> dict[str, object]:
        """Carry out ``cmd``; the reply names the state the chart is in afterwards."""
        chart = self._control.chart
        verb = cmd.verb
        if not chart.can(verb):
            raise CommandRefused(f"cannot {verb} in state {chart.state}")
        if verb == "start":
            await self._start(cmd.request or StartRequest())
        elif verb in ("pause", "stop"):
            await self._control.cancel_work()
            await self._devices.safe_stop()
            await self._control.fire(Outcome(verb))
        elif verb == "fault":
            if chart.state == "fault":  # one cause, many reporters (telemetry, events, the work)
                _info("fault_already", reason=cmd.reason)
                return {"state": chart.state}
            await self._control.cancel_work()
            await self._control.advance(Outcome("fault", {"reason": cmd.reason}))
        elif verb == "estop":
            await self._control.cancel_work()
            await self._devices.safe_stop()
            await self._devices.relax()
            await self._control.fire(Outcome("estop"))
        elif verb in ("resume", "reset"):
            if verb == "reset":
                await self._devices.clear()
            self._control.context.rejoin = verb == "resume"
            await self._control.fire(Outcome(verb))
        else:
            raise CommandRefused(f"unknown command {verb!r}")
        return {"state": chart.state}

    async def _start(self, request: StartRequest) -> None:
        problems = self._devices.start_problems()
        if problems:
            raise CommandRefused("; ".join(problems))
        self._control.begin(self._new_context(request))
        await self._control.fire(Outcome("start"))

    def _new_context(self, request: StartRequest) -> JobContext:
        """A new job's context: a new scene (a dataset or mugs to set the simulated counter up with) starts
        with an empty tray; on the same scene, what earlier jobs put on the tray is still there."""
        options = request.planner.options(self._services.config.planner)
        if request.dataset is not None or request.mugs is not None:
            self._set_counter(request)
            return JobContext(planner=options)
        return self._control.context.next_job(options)

    def _set_counter(self, request: StartRequest) -> None:
        backend = self._services.backend
        if backend.counter is None:
            raise CommandRefused("dataset and mugs set up a simulated counter; this backend is real hardware")
        try:
            tray = backend.counter.set_counter(dataset=request.dataset, mugs=request.mugs)
        except ValueError as e:
            raise CommandRefused(str(e)) from e
        if tray != backend.tray and backend.motion_for is not None:
            backend.motion = backend.motion_for(tray)
        backend.tray = tray
        self._services.event(SceneSetEvent(scene=backend.scene()))  # the recording's header has the first


def _info(event: str, **fields: object) -> None:
    """Log where a failing log call must not change what the job does next (see ``runner._say``)."""
    with contextlib.suppress(Exception):
        log.info(event, **fields)
