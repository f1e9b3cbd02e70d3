"""Device supervision for the job: what the drivers report while it runs, whether the devices allow a start
or a reset, and bringing the arm to rest.

The runner hands every driver event here (``on_event``); a lost bus, and a silent or unplugged force sensor
while the job works, become faults through the ``fault`` callback the runner gives. The arm is brought to rest
with every device failure suppressed: stopping is what a failing device asks for anyway.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Coroutine, Mapping

import structlog

from daemon.job.errors import CommandRefused
from daemon.job.services import Services
from drivers.errors import BusLost, DriverError
from wire.messages import UNSET, BadMessage, Event, EventKind, as_message

log = structlog.get_logger("daemon.job")

# How long the force sensor may be lost or silent while the job works before it faults (see on_event).
FORCE_GRACE_S = 0.3

_FORCE_SILENT = "the gripper's force sensor is not reporting (lost or silent); check the FSR Arduino"


class DeviceSupervisor:
    """Watches the job's devices: driver events, the start and reset checks, the safe stop."""

    def __init__(
        self,
        services: Services,
        *,
        working: Callable[[], bool],
        fault: Callable[[str], Coroutine[object, object, None]],
        force_grace_s: float = FORCE_GRACE_S,
    ) -> None:
        """``working`` says whether the job is working now; ``fault`` enters fault with a reason (the
        runner's command, so a fault is taken in turn with every other command)."""
        self._services = services
        self._working = working
        self._fault = fault
        self._force_grace_s = force_grace_s
        self._force_down = 0  # FSR lost/stale reports since it was last restored

    def on_event(self, event: Mapping[str, object], state: str) -> None:
        """A driver's fault or recovery (``daemon.messages.device_event_payload``), on the event loop:
        published on ``events``; a lost bus, and a silent or unplugged force sensor while a job works (a
        drop could no longer be seen), fault the job. Servo faults and warnings are only reported here: the
        gripper recovers overloads itself, and a fault that stands reaches the job as the driver's exception
        (from its work, the telemetry or the health poll). However many of them report one cause, the job
        faults once."""
        self._services.publish("events", {**event, "state": state})  # a driver's keys first: a mapping
        try:
            heard = as_message(event, Event, name="events")
        except BadMessage as e:  # a field of another type than declared: its kind still decides
            log.warning("device_event_field_unexpected", error=str(e))
            heard = Event(kind=as_message(event, EventKind, name="events").kind)
        kind = heard.kind
        where = heard.port if heard.port is not UNSET else heard.device if heard.device is not UNSET else "?"
        reason = f"{kind} on {where}"
        if heard.error is not UNSET:
            reason += f": {heard.error}"
        if kind == "bus_lost":
            asyncio.get_running_loop().create_task(self._fault(reason))
        elif kind in ("fsr_lost", "fsr_stale"):
            self._force_down += 1
            if self._working():
                asyncio.get_running_loop().create_task(self._fault_unless_force_back(reason))
        elif kind == "fsr_restored":
            self._force_down = 0

    def start_problems(self) -> list[str]:
        """What stands against a start: a force sensor that is not reporting, a device in error."""
        problems = []
        if self._force_down:
            problems.append(_FORCE_SILENT)
        health = self._services.backend.health
        if health is not None:
            problems += health.problems()
        return problems

    async def clear(self) -> None:
        """Reset's device check: clear what can be cleared (a tripped servo, a bus plugged back in);
        ``CommandRefused``, naming what still stands, when anything does."""
        problems: list[str] = []
        health = self._services.backend.health
        if health is not None:
            try:
                problems += await health.clear()
            except (DriverError, BusLost) as e:
                problems.append(str(e))
        if self._force_down:
            problems.append(_FORCE_SILENT)
        if problems:
            log.warning("reset_refused", problems=problems)
            raise CommandRefused("cannot reset: " + "; ".join(problems))

    async def safe_stop(self) -> None:
        """Hold the arm and the gripper where they are (each device's failure is suppressed)."""
        backend = self._services.backend
        with contextlib.suppress(DriverError, BusLost):
            await backend.arm.stop()
        with contextlib.suppress(DriverError, BusLost):
            await backend.gripper.stop()

    async def stop_arm(self) -> None:
        """Hold the arm where it is (the process is exiting)."""
        with contextlib.suppress(DriverError, BusLost):
            await self._services.backend.arm.stop()

    async def relax(self) -> None:
        """Take the torque off the arm (emergency stop)."""
        with contextlib.suppress(DriverError, BusLost):
            await self._services.backend.arm.relax()

    async def _fault_unless_force_back(self, reason: str) -> None:
        """Fault the job when the force sensor is still lost or silent after the grace time: a short stall of
        the event loop must not end a job, a sensor that stays away must (no drop could be seen)."""
        await self._services.sleep(self._force_grace_s)
        if self._force_down and self._working():
            await self._fault(reason)
