"""Device faults reach the daemon (issue 5, items 2-3): the daemon runs on the hardware backend, whose real
drivers talk to the simulated servo chain and FSR Arduino over pseudo-terminals, and a second Zenoh session
watches what it publishes. Each fault is injected with the simulators' hooks; each test asserts the state the
daemon ends in and the event it publishes."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from tests.fakes.hw_rig import GRIPPER_ID, Daemon, Rig, rig, running_daemon


def _run(tmp_path: Path, scenario: Callable[[Rig, Daemon], Awaitable[None]], **kw: Any) -> None:
    async def go() -> None:
        with rig() as r:
            async with running_daemon(r, tmp_path, **kw) as d:
                await scenario(r, d)

    asyncio.run(go())


def test_a_gripper_overload_is_recovered_reported_and_the_job_goes_on(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        # The servo trips the first time a closing goal reaches it (a jam), then closes normally.
        r.servos.overload(GRIPPER_ID, now=False, repeats=1)
        assert (await d.command("start"))["ok"]
        await d.until(lambda: d.reached("done", "fault"))
        assert d.reached("done")
        trip = d.event("servo_fault")
        assert (trip["device"], trip["servo_id"], trip["faults"]) == ("servo/6", 6, "['overload']")
        recovered = d.event("gripper_overload_recovered")
        assert (recovered["servo_id"], recovered["state"]) == (6, "side_grasp.close")
        assert d.kinds().count("gripper_overload_recovered") == 1
        assert "mug_placed" in d.kinds()

    _run(tmp_path, scenario)


def test_a_gripper_that_keeps_tripping_faults_the_job_and_only_reset_leaves(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        r.servos.overload(GRIPPER_ID, now=False, repeats=50)
        assert (await d.command("start"))["ok"]
        await d.until(lambda: d.reached("done", "fault"))
        assert d.reached("fault")
        # The gripper's own recoveries all ran (the telemetry did not cut them short), then the fault stood.
        assert d.kinds().count("gripper_overload_recovered") == 3
        assert d.event("fault")["reason"].startswith("ServoFault: gripper servo 6 overloaded")
        assert (await d.command("start"))["error"] == "cannot start in state fault"
        assert (await d.command("reset"))["state"] == "idle"

    _run(tmp_path, scenario)


def test_an_arm_servo_that_stays_overloaded_faults_the_idle_daemon_after_the_grace(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        r.servos.overload(2)
        await d.until(lambda: d.reached("fault"))
        assert d.event("servo_fault")["servo_id"] == 2
        fault = d.event("fault")
        assert fault["reason"].startswith("ServoFault: servo 2 on ")
        assert fault["reason"].endswith("reports overload; its torque is off until the fault is cleared")
        # the grace: the telemetry saw the fault for a second before it faulted the daemon
        assert fault["t"] - d.event("servo_fault")["t"] >= 0.9

    _run(tmp_path, scenario)


def test_a_servo_that_stops_answering_faults_the_daemon_naming_it(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        r.servos.silence(3)
        await d.until(lambda: d.reached("fault"))
        assert (d.event("servo_fault")["servo_id"], d.event("servo_fault")["faults"]) == (3, "['no_status']")
        reason = d.event("fault")["reason"]
        assert reason.startswith("BusTimeout: servo")
        assert f" 3 did not answer on {r.servos.device_path} after 3 tries" in reason

    _run(tmp_path, scenario)


def test_corrupt_packets_are_retried_and_counted_without_a_fault(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        assert d.backend.devices is not None
        r.servos.corrupt(4, packets=2)
        await d.until(
            lambda: d.backend.devices is not None and d.backend.devices.chain.counters()[4].corrupt >= 2
        )
        await asyncio.sleep(0.3)
        counters = d.backend.devices.chain.counters()[4]
        assert counters.corrupt == 2
        assert counters.retries >= 2
        assert d.state == "idle"
        assert "fault" not in d.kinds()

    _run(tmp_path, scenario)


def test_unplugging_the_servo_adapter_reports_the_lost_bus_and_faults(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        assert (await d.command("start"))["ok"]
        await d.until(lambda: d.state.startswith("side_grasp"))
        r.servos.unplug()
        await d.until(lambda: d.reached("fault"))
        lost = d.event("bus_lost")
        assert lost["device"] == "bus"
        assert lost["port"] == r.servos.device_path
        assert "fault" in d.kinds()
        assert "mug_placed" not in d.kinds()

    _run(tmp_path, scenario)


def test_a_silent_force_sensor_while_carrying_faults_the_job(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        assert (await d.command("start"))["ok"]
        await d.until(lambda: d.state == "flip.transit")
        r.fsr.silence()
        await d.until(lambda: d.reached("fault"))
        stale = d.event("fsr_stale")
        assert (stale["device"], stale["port"]) == ("fsr", r.fsr.device_path)
        assert d.event("fault")["reason"] == f"fsr_stale on {r.fsr.device_path}"
        r.fsr.silence(on=False)
        await d.until(lambda: "fsr_restored" in d.kinds())

    _run(tmp_path, scenario, carry_s=1.5)


def test_an_unplugged_force_sensor_while_idle_is_reported_and_refuses_a_start_until_back(
    tmp_path: Path,
) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        r.fsr.unplug()
        await d.until(lambda: "fsr_lost" in d.kinds())
        assert d.event("fsr_lost")["port"] == r.fsr.device_path
        assert (await d.command("start"))["error"] == (
            "the gripper's force sensor is not reporting (lost or silent); check the FSR Arduino"
        )
        r.fsr.replug()
        await d.until(lambda: "fsr_restored" in d.kinds())
        assert d.state == "idle"
        assert "fault" not in d.kinds()
        assert (await d.command("start"))["ok"]

    _run(tmp_path, scenario)


def test_the_force_dropping_while_carrying_recovers_the_lost_mug(tmp_path: Path) -> None:
    async def scenario(r: Rig, d: Daemon) -> None:
        assert (await d.command("start"))["ok"]
        await d.until(lambda: d.state == "flip.transit")
        r.fsr.drop_force()
        await d.until(lambda: d.state == "recover_lost_mug")
        r.fsr.drop_force(on=False)
        d.motion.carry_s = 0.1  # the second attempt need not be slow
        await d.until(lambda: d.reached("done", "fault"))
        assert d.reached("done")
        dropped = d.event("mug_dropped")
        assert (dropped["state"], dropped["mug_id"]) == ("flip.transit", "m1")
        assert d.event("mug_found")["mug_id"] == "m1"
        assert "mug_placed" in d.kinds()

    _run(tmp_path, scenario, carry_s=1.5)
