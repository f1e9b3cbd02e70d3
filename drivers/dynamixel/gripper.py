"""The gripper servo, implementing ``drivers.interfaces.GripperDriver``, with an overload recovery policy.

The thesis's real-robot runs ended because the AX-12A gripper tripped its overload protection while closing
on a mug (§5.3.3). Here the gripper closes in small steps under a reduced torque limit, never letting the
goal run more than two steps ahead of where the pads really are, and once the force sensor passes the
threshold (§4.3.1) it keeps squeezing: the goal stays two steps past the pads, under that same limit, as a
position-controlled Dynamixel gripper has to be driven to keep its grip. When the servo still trips, it is
stopped, relaxed, its torque restored (1.0: rewrite Torque Limit, which the servo dropped to 0; 2.0: reboot),
re-enabled at its present position, and the close is retried under a lower limit; after
``overload_retries`` recoveries the fault stands.
"""

from __future__ import annotations

import functools
from types import TracebackType

import structlog

from drivers.dynamixel.bus import DynamixelBus, ServoReading
from drivers.dynamixel.chain import ServoChain
from drivers.dynamixel.config import GripperSpec
from drivers.errors import ServoFault
from drivers.interfaces import ForceSensor, GraspResult, GripperState

log = structlog.get_logger("drivers.dynamixel.gripper")


class DynamixelGripper:
    """The gripper on a verified :class:`ServoChain`; ``force_sensor`` is the FSR in its pad."""

    def __init__(
        self,
        chain: ServoChain,
        spec: GripperSpec,
        force_sensor: ForceSensor,
        *,
        timeout_s: float = 6.0,
        force_max_age_s: float = 0.25,
    ) -> None:
        self._chain = chain
        self._clock = chain.clock
        self.spec = spec
        self._force_sensor = force_sensor
        self.timeout_s = timeout_s
        self.force_max_age_s = force_max_age_s
        self.overload_recoveries = 0
        self._squeeze_goal_m: float | None = None  # set while the pads squeeze a mug, until the next open
        self._id = spec.servo_id
        self._log = log.bind(servo_id=spec.servo_id)

    # ------------------------------------------------------------------------------------------ lifecycle

    async def start(self) -> None:
        """Hold the pads where they are, set the full grip limit, enable the torque."""
        limit = self._limit_ticks(1.0)

        def enable(bus: DynamixelBus) -> ServoReading:
            reading = bus.read_states([self._id])[self._id]
            bus.write_goals({self._id: (reading.position_rad, self.spec.speed_rad_s)})
            bus.write_register(self._id, self._limit_register, limit)
            bus.write_register(self._id, "torque_enable", 1)
            return reading

        await self._chain.call(enable)

    async def shutdown(self) -> None:
        await self._chain.call(lambda bus: bus.write_register(self._id, "torque_enable", 0, check=False))

    async def __aenter__(self) -> DynamixelGripper:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.shutdown()

    # ------------------------------------------------------------------------------------------ GripperDriver

    async def read(self) -> GripperState:
        reading = await self._read()
        return GripperState(
            self._clock.monotonic(), self.spec.aperture_for(reading.position_rad), reading.load
        )

    async def open(self, aperture_m: float | None = None) -> None:
        """Open to ``aperture_m`` (at most ``open_aperture_m``; never closing) or fully, at the full grip
        limit, and wait until there (or the timeout)."""
        self._squeeze_goal_m = None
        target = self.spec.open_aperture_m
        if aperture_m is not None:
            present = self.spec.aperture_for((await self._read()).position_rad)
            target = max(min(aperture_m, target), present)
        angle = self.spec.angle_for(target)
        limit = self._limit_ticks(1.0)

        def command(bus: DynamixelBus) -> None:
            bus.write_register(self._id, self._limit_register, limit)
            bus.write_goals({self._id: (angle, self.spec.speed_rad_s)})

        await self._chain.call(command)
        deadline = self._clock.monotonic() + self.timeout_s
        while self._clock.monotonic() < deadline:
            if abs((await self._read()).position_rad - angle) < 0.05:
                return
            await self._clock.sleep(self.spec.step_period_s)
        self._log.warning("gripper_open_timeout", aperture_m=round(target, 4))

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        """Close step by step until the force passes the threshold (held) or the opening gets too small."""
        limit = self.spec.grip_limit
        recoveries = 0
        self._squeeze_goal_m = None
        await self._set_limit(limit)
        while True:
            try:
                return await self._close(force_threshold_n, min_aperture_m)
            except ServoFault as e:
                if e.servo_id != self._id or "overload" not in e.bits:
                    raise
                recoveries += 1
                if recoveries > self.spec.overload_retries:
                    raise ServoFault(
                        f"gripper servo {self._id} overloaded {recoveries} times while closing, the "
                        f"last time at {limit:.0%} of full torque; check the gripper for a jam and "
                        "power-cycle the servo",
                        servo_id=self._id,
                        bits=("overload",),
                    ) from e
                limit *= self.spec.grip_limit_backoff
                await self._recover(limit)

    async def stop(self) -> None:
        """Stop the jaw: hold the present opening, or, while a held grasp squeezes a mug, keep squeezing
        (a pause mid-carry must not let the mug slip out)."""
        squeeze = self._squeeze_goal_m
        speed = self.spec.speed_rad_s

        def hold(bus: DynamixelBus) -> None:
            if squeeze is not None:
                bus.write_goals({self._id: (self.spec.angle_for(squeeze), speed)})
                return
            reading = bus.read_states([self._id])[self._id]
            bus.write_goals({self._id: (reading.position_rad, speed)})

        await self._chain.call(hold)

    # ------------------------------------------------------------------------------------------ internals

    @property
    def _limit_register(self) -> str:
        return "torque_limit" if self.spec.spec.protocol == 1 else "goal_pwm"

    def _limit_ticks(self, fraction: float) -> int:
        return max(1, round(self.spec.spec.default_torque_limit * fraction))

    async def _read(self) -> ServoReading:
        return (await self._chain.call(lambda bus: bus.read_states([self._id])))[self._id]

    async def _set_limit(self, fraction: float) -> None:
        ticks = self._limit_ticks(fraction)
        await self._chain.call(lambda bus: bus.write_register(self._id, self._limit_register, ticks))

    def _force(self) -> float:
        """The pad force, or 0 when the sensor has nothing fresh: a frozen reading never counts as held."""
        reading = self._force_sensor.latest()
        if reading is None or self._clock.monotonic() - reading.t > self.force_max_age_s:
            return 0.0
        return reading.force_n

    async def _close(self, threshold_n: float, min_aperture_m: float) -> GraspResult:
        spec = self.spec
        aperture = spec.aperture_for((await self._read()).position_rad)
        command = aperture
        deadline = self._clock.monotonic() + self.timeout_s
        while True:
            force = self._force()
            if force >= threshold_n:
                squeeze = await self._hold_squeeze(aperture)
                self._log.info("grasp_held", force_n=force, aperture_m=aperture, squeeze_goal_m=squeeze)
                return GraspResult(True, force, aperture)
            if aperture < min_aperture_m:
                await self.stop()
                reason = (
                    f"aperture {aperture:.3f} m fell below {min_aperture_m:.3f} m before the force passed "
                    f"{threshold_n:.2f} N (peak now {force:.2f} N)"
                )
                self._log.info("grasp_missed", reason=reason)
                return GraspResult(False, force, aperture, reason)
            if self._clock.monotonic() > deadline:
                await self.stop()
                reason = f"closing took longer than {self.timeout_s:.1f} s; the pads are at {aperture:.3f} m"
                return GraspResult(False, force, aperture, reason)
            # Never let the goal run more than two steps ahead of the pads: a blocked gripper then pushes
            # with a bounded error instead of winding up towards an overload.
            command = max(command - spec.step_m, aperture - 2 * spec.step_m)
            goal = {self._id: (spec.angle_for(command), spec.speed_rad_s)}
            reading = (await self._chain.call(functools.partial(_write_then_read, goal=goal)))[self._id]
            aperture = spec.aperture_for(reading.position_rad)
            await self._clock.sleep(spec.step_period_s)

    async def _hold_squeeze(self, aperture_m: float) -> float:
        """Keep squeezing the mug: leave the goal ``2 * step_m`` past where the pads stopped.

        A position servo pushes in proportion to how far its goal lies beyond where it stands, capped by its
        torque limit (still the reduced grip limit of the close). Holding the *present* position, as
        :meth:`stop` does, would let the squeeze relax to nothing within a second and the mug slip out; a
        goal a little past contact keeps the force the close ended with, the same bounded error the close
        itself never exceeds, so it cannot wind up towards an overload. Returns the goal aperture."""
        goal_m = aperture_m - 2 * self.spec.step_m
        goal = {self._id: (self.spec.angle_for(goal_m), self.spec.speed_rad_s)}
        await self._chain.call(lambda bus: bus.write_goals(goal))
        self._squeeze_goal_m = goal_m
        return goal_m

    async def _recover(self, limit: float) -> None:
        """Stop, relax, restore the torque (1.0) or reboot (2.0), re-enable where the pads are."""
        ticks = self._limit_ticks(limit)
        protocol = self.spec.spec.protocol
        servo_id = self._id

        def recover(bus: DynamixelBus) -> None:
            bus.write_register(servo_id, "torque_enable", 0, check=False)
            if protocol == 1:
                bus.write_register(servo_id, "torque_limit", ticks, check=False)
            else:
                bus.reboot(servo_id)
                bus.write_register(servo_id, "goal_pwm", ticks)
            present = bus.read_register(servo_id, "present_position")
            bus.write_register(servo_id, "goal_position", present)
            bus.write_register(servo_id, "torque_enable", 1)
            bus.clear_fault(servo_id)
            bus.emit("gripper_overload_recovered", f"servo/{servo_id}", servo_id=servo_id, grip_limit=limit)

        self.overload_recoveries += 1
        self._log.warning("gripper_overload_recovery", attempt=self.overload_recoveries, grip_limit=limit)
        await self._chain.call(recover)


def _write_then_read(bus: DynamixelBus, goal: dict[int, tuple[float, float]]) -> dict[int, ServoReading]:
    bus.write_goals(goal)
    return bus.read_states(list(goal))
