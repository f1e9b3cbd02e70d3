"""The job's device supervision on its own (``daemon.job.devices``): which driver reports fault the job and
when, what stands against a start or a reset; on simulated time, with the job's fake devices."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job.devices import FORCE_GRACE_S, DeviceSupervisor
from daemon.job.errors import CommandRefused
from daemon.job.services import Services
from perception import associate
from tests.fakes.job import make_backend, make_world
from wire.messages import plain

SILENT = "the gripper's force sensor is not reporting (lost or silent); check the FSR Arduino"


class _Watched:
    """A supervisor with what it published and the faults it asked for, working or not as set."""

    def __init__(self, clock: SimulatedClock, *, working: bool) -> None:
        self.published: list[tuple[str, dict[str, Any]]] = []
        self.faults: list[tuple[float, str]] = []
        self.working = working
        self.clock = clock
        self.backend = make_backend(make_world(1), clock=clock)
        services = Services(
            self.backend,
            load_config(),
            lambda topic, payload: self.published.append((topic, dict(plain(payload)))),
            associate,
            state=lambda: "idle",
        )
        self.devices = DeviceSupervisor(services, working=lambda: self.working, fault=self._fault)

    async def _fault(self, reason: str) -> None:
        self.faults.append((self.clock.monotonic(), reason))


def test_a_lost_bus_is_published_with_the_state_and_faults_the_job_at_once() -> None:
    clock = SimulatedClock()

    async def go() -> _Watched:
        w = _Watched(clock, working=False)
        w.devices.on_event({"kind": "bus_lost", "port": "/dev/servos", "error": "gone"}, "place.descend")
        await clock.sleep(0.0)
        return w

    w = clock.run(go())
    assert w.published == [
        ("events", {"kind": "bus_lost", "port": "/dev/servos", "error": "gone", "state": "place.descend"})
    ]
    assert [reason for _, reason in w.faults] == ["bus_lost on /dev/servos: gone"]


@pytest.mark.parametrize("kind", ["fsr_lost", "fsr_stale"])
def test_a_force_sensor_gone_while_working_faults_after_the_grace_time(kind: str) -> None:
    clock = SimulatedClock()

    async def go() -> tuple[float, _Watched]:
        w = _Watched(clock, working=True)
        t0 = clock.monotonic()
        w.devices.on_event({"kind": kind, "device": "fsr"}, "flip.transit")
        await clock.sleep(FORCE_GRACE_S + 0.1)
        return t0, w

    t0, w = clock.run(go())
    ((at, reason),) = w.faults
    assert reason == f"{kind} on fsr"
    assert at - t0 == pytest.approx(FORCE_GRACE_S)


def test_a_force_sensor_back_within_the_grace_time_faults_nothing_and_allows_a_start() -> None:
    clock = SimulatedClock()

    async def go() -> _Watched:
        w = _Watched(clock, working=True)
        w.devices.on_event({"kind": "fsr_lost", "device": "fsr"}, "flip.transit")
        await clock.sleep(FORCE_GRACE_S / 2)
        w.devices.on_event({"kind": "fsr_restored", "device": "fsr"}, "flip.transit")
        await clock.sleep(FORCE_GRACE_S)
        return w

    w = clock.run(go())
    assert w.faults == []
    assert w.devices.start_problems() == []


def test_a_force_sensor_gone_while_idle_faults_nothing_but_refuses_a_start_and_a_reset() -> None:
    clock = SimulatedClock()

    async def go() -> tuple[_Watched, str]:
        w = _Watched(clock, working=False)
        w.devices.on_event({"kind": "fsr_stale", "device": "fsr"}, "idle")
        await clock.sleep(FORCE_GRACE_S * 2)
        with pytest.raises(CommandRefused) as refused:
            await w.devices.clear()
        return w, str(refused.value)

    w, reset = clock.run(go())
    assert w.faults == []
    assert w.devices.start_problems() == [SILENT]
    assert reset == f"cannot reset: {SILENT}"


def test_the_safe_stop_and_relax_reach_the_arm_and_a_failing_device_is_suppressed() -> None:
    from drivers.errors import BusLost

    clock = SimulatedClock()
    w = _Watched(clock, working=True)
    backend = w.backend
    calls: list[str] = []

    async def stop() -> None:
        calls.append("arm.stop")
        raise BusLost("bus on /dev/servos is gone")

    async def gripper_stop() -> None:
        calls.append("gripper.stop")

    async def relax() -> None:
        calls.append("arm.relax")

    backend.arm.stop = stop  # type: ignore[method-assign]
    backend.gripper.stop = gripper_stop  # type: ignore[method-assign]
    backend.arm.relax = relax  # type: ignore[method-assign]

    async def go() -> None:
        await w.devices.safe_stop()
        await w.devices.relax()
        await w.devices.stop_arm()

    asyncio.run(go())
    assert calls == ["arm.stop", "gripper.stop", "arm.relax", "arm.stop"]
