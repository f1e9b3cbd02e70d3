"""The whole daemon on the hardware backend, fast: the real device stack (dynamixel-sdk, the FSR reader) on
the in-process cables of the servo chain and FSR simulators, on a simulated clock, with ``serve`` (the job,
the telemetry and health loops, a Zenoh session on loopback, the recording) as the robot runs it.

Commands go in through the serve hooks' ``handle`` (as if by Zenoh) and what the daemon publishes is seen
through ``on_publish``, in order; waiting is on simulated time, so a scenario takes milliseconds of wall
time and comes out the same every run. The physical world is ``tests.fakes.hw_rig``'s: one mug on the
counter, the pad force rising when the gripper closes past it, short planned moves."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.app import ServeContext
from daemon.backend import Backend
from daemon.clock import SimulatedClock
from daemon.config import Config, load_config
from daemon.hardware import open_hardware_backend
from drivers.sim import FsrSimulator, ServoChainSimulator, default_chain
from drivers.sim.plant import FirstOrderPlant
from drivers.stack import ARM_JOINTS
from tests.fakes.daemon import running_daemon
from tests.fakes.hw_rig import CONTACT_RAD, GRIP_N, GRIPPER_ID, CounterStandIn, ShortMoves

ROBOT = "inproc"
JOINTS = (*ARM_JOINTS, "gripper")
P2_MODEL = "XL430-W250"


@dataclass
class SimDaemon:
    """A daemon running on the in-process rig, and everything it published on ``events`` and ``state``."""

    clock: SimulatedClock
    servos: ServoChainSimulator
    fsr: FsrSimulator
    plant: FirstOrderPlant
    config: Config
    backend: Backend | None = None
    ctx: ServeContext | None = None
    events: list[dict[str, Any]] = field(default_factory=list)
    states: list[str] = field(default_factory=list)

    def kinds(self) -> list[str]:
        return [str(e["kind"]) for e in self.events]

    def event(self, kind: str) -> dict[str, Any]:
        return next(e for e in self.events if e["kind"] == kind)

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["kind"] == kind]

    @property
    def state(self) -> str:
        assert self.ctx is not None
        return self.ctx.job.chart.state

    def reached(self, *states: str) -> bool:
        return any(e["kind"] == "transition" and e["dest"] in states for e in self.events)

    async def until(
        self, condition: Callable[[], bool], *, timeout_s: float = 30.0, step_s: float = 0.001
    ) -> None:
        """Wait (in simulated time) until ``condition`` holds."""
        deadline = self.clock.monotonic() + timeout_s
        while not condition():
            if self.clock.monotonic() > deadline:
                raise TimeoutError(f"not within {timeout_s} simulated s; last events: {self.kinds()[-8:]}")
            await self.clock.sleep(step_s)

    async def command(self, verb: str, body: Mapping[str, Any] | None = None) -> dict[str, Any]:
        assert self.ctx is not None
        return dict(await self.ctx.handle(verb, json.dumps(dict(body or {})).encode(), False))

    def pad_force_n(self) -> float:
        return GRIP_N if self.plant.present(GRIPPER_ID)[0] >= CONTACT_RAD else 0.0


def rig_config(servos: ServoChainSimulator, fsr: FsrSimulator, *, protocol: int, **overrides: Any) -> Config:
    hardware: dict[str, Any] = {
        "servo_port": servos.device_path,
        "camera": "none",
        "protocol": protocol,
        "read_timeout_s": 0.01,
        "fsr": {"port": fsr.device_path},
    }
    if protocol == 2:
        hardware["servos"] = {j: {"id": i, "model": P2_MODEL} for i, j in enumerate(JOINTS, start=1)}
    for key, value in overrides.pop("hardware", {}).items():
        hardware[key] = {**hardware.get(key, {}), **value} if isinstance(value, dict) else value
    base: dict[str, Any] = {
        "robot_id": ROBOT,
        "backend": "hardware",
        "planner": {"method": "bh"},
        "daemon": {"drop_check_period_s": 0.01},
        "hardware": hardware,
        **overrides,
    }
    return load_config(overrides=base)


def run_daemon(
    tmp_path: Path,
    scenario: Callable[[SimDaemon], Awaitable[None]],
    *,
    protocol: int = 1,
    carry_s: float = 0.4,
    **overrides: Any,
) -> SimDaemon:
    """Run ``scenario`` against a daemon on the in-process rig; returns the rig with what was published."""
    clock = SimulatedClock()

    async def main() -> SimDaemon:
        plant = FirstOrderPlant(clock=clock.monotonic)
        chain = default_chain() if protocol == 1 else tuple((i, P2_MODEL) for i in range(1, 7))
        servos = ServoChainSimulator(chain, protocol=protocol, plant=plant)  # type: ignore[arg-type]
        holder: list[SimDaemon] = []
        fsr = FsrSimulator(lambda: holder[0].pad_force_n() if holder else 0.0)
        servos.start_in_process(clock)
        fsr.start_in_process(clock)
        try:
            config = rig_config(servos, fsr, protocol=protocol, **overrides)
            d = SimDaemon(clock, servos, fsr, plant, config)
            holder.append(d)
            backend = await open_hardware_backend(
                config, clock=clock, open_bus=servos.open_serial, open_fsr=fsr.open_serial
            )
            backend = dataclasses.replace(
                backend,
                observer=CounterStandIn(lambda: "mug_placed" in d.kinds()),
                motion=ShortMoves(carry_s=carry_s),
            )
            d.backend = backend

            def tap(topic: str, payload: Mapping[str, object]) -> None:
                if topic == "events":
                    d.events.append(dict(payload))
                elif topic == "state":
                    d.states.append(str(payload["state"]))

            async with running_daemon(config, backend, tmp_path, on_publish=(tap,)) as running:
                d.ctx = running.context
                await scenario(d)
            return d
        finally:
            servos.stop()
            fsr.stop()

    return clock.run(main())
