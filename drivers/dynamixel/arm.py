"""The arm's five joints on a Dynamixel chain, implementing ``drivers.interfaces.ArmDriver``."""

from __future__ import annotations

import asyncio
import functools
import math
from collections.abc import Sequence
from types import TracebackType

import numpy as np
import structlog

from drivers.dynamixel.bus import DynamixelBus, ServoReading
from drivers.dynamixel.chain import ServoChain
from drivers.dynamixel.config import JointSpec
from drivers.errors import LimitViolation
from drivers.interfaces import JointState, JointTrajectory

log = structlog.get_logger("drivers.dynamixel.arm")

# How far past a joint limit a goal may be and still count as at it: floating-point rounding of a plan that
# goes up to the limit (one encoder step of an AX-12A is 5.1e-3 rad, of an MX-T 1.5e-3 rad).
LIMIT_SLACK_RAD = 1e-6


class DynamixelArm:
    """Joint-space control of the arm over a verified :class:`ServoChain`.

    ``follow`` streams goals at ``rate_hz`` by sync write and reads every joint back in the same bus turn;
    every goal is checked against the joints' software limits before it is sent. ``shutdown`` (and leaving
    the ``async with`` block) parks the arm at ``park_rad`` when given and turns the torque off. Periods,
    the settle deadline and the joint states' ``t`` are on the chain's clock.
    """

    def __init__(
        self,
        chain: ServoChain,
        joints: Sequence[JointSpec],
        *,
        rate_hz: float = 50.0,
        park_rad: Sequence[float] | None = None,
        park_speed_rad_s: float = 0.5,
        max_speed_rad_s: float = 3.0,
        settle_tolerance_rad: float = 0.03,
        settle_timeout_s: float = 2.0,
    ) -> None:
        if not joints:
            raise ValueError("the arm needs at least one joint")
        if park_rad is not None and len(park_rad) != len(joints):
            raise ValueError(f"park_rad has {len(park_rad)} values for {len(joints)} joints")
        self._chain = chain
        self._clock = chain.clock
        self.joints = tuple(joints)
        self._ids = tuple(j.servo_id for j in self.joints)
        self.period_s = 1.0 / rate_hz
        self.park_rad = tuple(park_rad) if park_rad is not None else None
        self.park_speed_rad_s = park_speed_rad_s
        self.max_speed_rad_s = max_speed_rad_s
        self.settle_tolerance_rad = settle_tolerance_rad
        self.settle_timeout_s = settle_timeout_s
        self.last_state: JointState | None = None
        self._torque = False
        if park_rad is not None:
            self.check_limits(park_rad)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    # ------------------------------------------------------------------------------------------ lifecycle

    async def start(self) -> None:
        """Hold every joint where it is, then enable the torque (no jump to a stale goal)."""
        ids = self._ids

        def enable(bus: DynamixelBus) -> dict[int, ServoReading]:
            readings = bus.read_states(ids)
            bus.write_goals({i: (readings[i].position_rad, self.park_speed_rad_s) for i in ids})
            for servo_id in ids:
                bus.write_register(servo_id, "torque_enable", 1)
            return readings

        self._state(await self._chain.call(enable))
        self._torque = True
        log.info("arm_torque_on", joints=list(self.joint_names))

    async def shutdown(self) -> None:
        """Park (when a park pose is configured) and turn the torque off, whatever happens while parking."""
        try:
            if self.park_rad is not None and self._torque:
                await self.park()
        finally:
            await self.relax()

    async def __aenter__(self) -> DynamixelArm:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.shutdown()

    # ------------------------------------------------------------------------------------------ ArmDriver

    async def read_joints(self) -> JointState:
        return self._state(await self._chain.call(lambda bus: bus.read_states(self._ids)))

    async def follow(self, trajectory: JointTrajectory) -> None:
        """Stream the trajectory; every point is limit-checked before the first goal goes out."""
        if trajectory.names != self.joint_names:
            raise ValueError(
                f"trajectory joints {trajectory.names} do not match the arm's {self.joint_names}"
            )
        positions = np.asarray(trajectory.positions, dtype=np.float64)
        for row in positions:
            self.check_limits(row)
        times = np.asarray(trajectory.times, dtype=np.float64)
        try:
            await self._stream(times, positions)
            await self._settle(positions[-1])
        except asyncio.CancelledError:
            await asyncio.shield(self.stop())
            raise

    async def move_to(self, positions: Sequence[float], *, speed_rad_s: float | None = None) -> None:
        """Go straight (in joint space) to ``positions`` at ``speed_rad_s`` and wait until there."""
        self.check_limits(positions)
        speed = speed_rad_s or self.park_speed_rad_s
        start = np.asarray((await self.read_joints()).position_rad)
        goal = np.asarray(positions, dtype=np.float64)
        duration = max(float(np.max(np.abs(goal - start))) / speed, self.period_s)
        await self.follow(
            JointTrajectory(self.joint_names, np.array([0.0, duration]), np.vstack([start, goal]))
        )

    async def park(self) -> None:
        if self.park_rad is None:
            raise ValueError("no park pose configured for this arm")
        await self.move_to(self.park_rad, speed_rad_s=self.park_speed_rad_s)
        log.info("arm_parked")

    async def stop(self) -> None:
        """Hold the present position of every joint."""

        def hold(bus: DynamixelBus) -> dict[int, ServoReading]:
            readings = bus.read_states(self._ids)
            bus.write_goals({i: (readings[i].position_rad, self.max_speed_rad_s) for i in self._ids})
            return readings

        self._state(await self._chain.call(hold))

    async def relax(self) -> None:
        """Torque off on every joint (tries them all even when one fails)."""

        def torque_off(bus: DynamixelBus) -> None:
            failure: Exception | None = None
            for servo_id in self._ids:
                try:
                    # Unchecked: a servo in a shutdown fault (overload, overheating) must still go limp, and
                    # its acknowledgement carries the fault's bits.
                    bus.write_register(servo_id, "torque_enable", 0, check=False)
                except Exception as e:  # keep going: every other joint must still go limp
                    failure = failure or e
            if failure is not None:
                raise failure

        await self._chain.call(torque_off)
        self._torque = False
        log.info("arm_torque_off")

    # ------------------------------------------------------------------------------------------ internals

    def check_limits(self, positions: Sequence[float] | np.ndarray) -> None:
        """Raise LimitViolation naming the first joint outside its software limits; nothing is sent. A goal
        a rounding error past a limit (``LIMIT_SLACK_RAD``, far below one encoder step) is at the limit:
        a planner that plans up to a limit computes it in floating point."""
        if len(positions) != len(self.joints):
            raise LimitViolation(f"{len(positions)} joint values for {len(self.joints)} joints")
        for joint, q in zip(self.joints, positions, strict=True):
            low, high = joint.min_rad - LIMIT_SLACK_RAD, joint.max_rad + LIMIT_SLACK_RAD
            value = float(q)  # a Python float compares faster than a NumPy scalar, and the same
            if not (low <= value <= high) or not math.isfinite(value):
                raise LimitViolation(
                    f"joint {joint.name} (servo {joint.servo_id}) goal {value:.4f} rad is outside its "
                    f"limits [{joint.min_rad:.4f}, {joint.max_rad:.4f}] rad; nothing was sent"
                )

    async def _stream(self, times: np.ndarray, positions: np.ndarray) -> None:
        t0 = self._clock.monotonic()
        ticks = self._ticks(times, positions)
        last = len(ticks) - 1
        for tick, goals in enumerate(ticks):
            self._state(await self._chain.call(functools.partial(_write_then_read, goals=goals)))
            if tick == last:
                return
            await self._clock.sleep_until(t0 + (tick + 1) * self.period_s)

    def _ticks(self, times: np.ndarray, positions: np.ndarray) -> list[dict[int, tuple[float, float]]]:
        """The goals of every control tick of a trajectory, computed at once before the first goes out.

        Tick ``k`` aims at the trajectory at ``t = min((k + 1) * period, duration)`` at the speed that covers
        the way from where the trajectory was a period earlier (20 % more, within [0.05, max] rad/s), each
        goal clamped to its joint's limits; the stream ends with the tick that reaches the duration. The
        numbers are those of one interpolation per tick (``np.interp`` gives each query point the same value
        whatever points it is asked with); only the per-tick work of computing them goes."""
        period = self.period_s
        duration = float(times[-1])
        stamps = []
        tick = 0
        while True:
            t = min((tick + 1) * period, duration)
            stamps.append(t)
            if t >= duration:
                break
            tick += 1
        at = np.asarray(stamps, dtype=np.float64)
        before = at - period
        columns = [np.ascontiguousarray(positions[:, k]) for k in range(positions.shape[1])]
        target = np.column_stack([np.interp(at, times, column) for column in columns])
        here = np.column_stack([np.interp(before, times, column) for column in columns])
        speed = np.clip(np.abs(target - here) / period * 1.2, 0.05, self.max_speed_rad_s)
        low = np.array([j.min_rad for j in self.joints])
        high = np.array([j.max_rad for j in self.joints])
        slack = LIMIT_SLACK_RAD
        outside = ~((target >= low - slack) & (target <= high + slack) & np.isfinite(target))
        if outside.any():
            self.check_limits(target[int(np.argmax(outside.any(axis=1)))])  # names the first one
        goal = np.minimum(np.maximum(target, low), high)
        ids = self._ids
        return [
            dict(zip(ids, zip(q, s, strict=True), strict=True))
            for q, s in zip(goal.tolist(), speed.tolist(), strict=True)
        ]

    async def _settle(self, final: np.ndarray) -> None:
        deadline = self._clock.monotonic() + self.settle_timeout_s
        while True:
            state = await self.read_joints()
            error = float(np.max(np.abs(np.asarray(state.position_rad) - final)))
            if error <= self.settle_tolerance_rad:
                return
            if self._clock.monotonic() >= deadline:
                log.warning("arm_settle_timeout", error_rad=error)
                return
            await self._clock.sleep(self.period_s)

    def _state(self, readings: dict[int, ServoReading]) -> JointState:
        ordered = [readings[i] for i in self._ids]
        self.last_state = JointState(
            t=self._clock.monotonic(),
            names=self.joint_names,
            position_rad=tuple(r.position_rad for r in ordered),
            velocity_rad_s=tuple(r.velocity_rad_s for r in ordered),
            load=tuple(r.load for r in ordered),
        )
        return self.last_state


def _write_then_read(bus: DynamixelBus, goals: dict[int, tuple[float, float]]) -> dict[int, ServoReading]:
    """One bus turn of the control loop: send every goal, then read every joint."""
    bus.write_goals(goals)
    return bus.read_states(list(goals))
