"""The kinematic cell's arm, gripper and force sensor: the ``drivers.interfaces`` protocols over the world."""

from __future__ import annotations

import numpy as np

from drivers.dynamixel import BusTimeout
from drivers.errors import LimitViolation, ServoFault
from drivers.interfaces import (
    FloatArray,
    ForceReading,
    GraspResult,
    GripperState,
    JointState,
    JointTrajectory,
)
from sim.kinematic.faults import ARM_SERVOS, GRIPPER_SERVO
from sim.kinematic.world import JAW_SPEED_M_S, OPEN_APERTURE_M, KinematicWorld

TICK_S = 0.01  # period (on the world's clock) at which a moving device updates the world
FSR_COUNTS_PER_N = 40.0  # ADC counts per newton of the simulated FSR (saturates at 1023)
# As the configured gripper (``hardware.gripper``): overload recoveries before a close gives up, and the
# torque limit each one backs off to.
OVERLOAD_RETRIES = 3
GRIP_LIMIT = 0.6
GRIP_LIMIT_BACKOFF = 0.75


class SimArm:
    """Joint-space motion at finite speed: a trajectory is followed at its own timing, slowed down where it
    asks for more than ``joint_speed_rad_s``; the servos first travel to the trajectory's start if needed."""

    def __init__(self, world: KinematicWorld, *, joint_speed_rad_s: float) -> None:
        self._world = world
        self._speed = joint_speed_rad_s
        self._last_q = world.q.copy()
        self._last_t = world.clock.now()
        self._velocity: FloatArray = np.zeros(world.arm.dof)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._world.arm.joint_names

    async def read_joints(self) -> JointState:
        self._world.check_bus(ARM_SERVOS)
        now = self._world.clock.now()
        q = self._world.q
        if now > self._last_t:
            self._velocity = (q - self._last_q) / (now - self._last_t)
            self._last_q, self._last_t = q.copy(), now
        load = 0.1 if self._world.held is not None else 0.0
        return JointState(
            t=now,
            names=self.joint_names,
            position_rad=tuple(float(v) for v in q),
            velocity_rad_s=tuple(float(v) for v in self._velocity),
            load=(load,) * len(q),
        )

    async def follow(self, trajectory: JointTrajectory) -> None:
        self._world.check_bus(ARM_SERVOS)
        if trajectory.names != self.joint_names:
            raise LimitViolation(
                f"trajectory {trajectory.label!r} names joints {trajectory.names}; "
                f"the arm has {self.joint_names}"
            )
        violations = [v for q in trajectory.positions for v in self._world.arm.limit_violations(q, tol=1e-6)]
        if violations:
            raise LimitViolation(f"trajectory {trajectory.label!r} leaves the joint limits: {violations[0]}")
        times, positions = _with_travel_to_start(self._world.q, trajectory, self._speed)
        times = _retime(times, positions, self._speed)
        clock = self._world.clock
        t0 = clock.now()
        while True:
            t = clock.now() - t0
            if t >= times[-1]:
                self._world.set_q(positions[-1])
                return
            self._world.set_q(_interpolate(times, positions, t))
            await clock.sleep(TICK_S)
            self._world.check_bus(ARM_SERVOS)

    async def stop(self) -> None:
        # Positions are only ever set to where the arm is, so holding still needs no command.
        self._world.check_bus(ARM_SERVOS)

    async def relax(self) -> None:
        self._world.check_bus(ARM_SERVOS)


class SimGripper:
    """A jaw that closes at finite speed; its pad force rises once it squeezes a mug."""

    def __init__(self, world: KinematicWorld) -> None:
        self._world = world

    async def read(self) -> GripperState:
        self._world.check_bus(_GRIPPER)
        return GripperState(
            t=self._world.clock.now(),
            aperture_m=self._world.aperture_m,
            load=min(1.0, self._world.pad_force_n() / 20.0),
        )

    async def open(self, aperture_m: float | None = None) -> None:
        # Opening rewrites the torque limit, which clears a latched shutdown whose cause is gone (1.0).
        faults = self._world.faults
        for name in ("overload", "overheating"):
            faults.clear(GRIPPER_SERVO, name)
        self._world.check_bus(_GRIPPER)
        self._world.release()
        target = OPEN_APERTURE_M if aperture_m is None else min(aperture_m, OPEN_APERTURE_M)
        await self._move_to(max(target, self._world.aperture_m))

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        """As the Dynamixel gripper driver: an overload while closing is recovered (relax, restore a lower
        torque limit, clear the fault) and the close tried again, up to ``OVERLOAD_RETRIES`` times."""
        faults = self._world.faults
        limit = GRIP_LIMIT
        recoveries = 0
        while True:
            try:
                return await self._close(force_threshold_n, min_aperture_m)
            except ServoFault as e:
                if isinstance(e, BusTimeout) or e.servo_id != GRIPPER_SERVO or "overload" not in e.bits:
                    raise
                recoveries += 1
                if recoveries > OVERLOAD_RETRIES:
                    raise ServoFault(
                        f"gripper servo {GRIPPER_SERVO} overloaded {recoveries} times while closing, the "
                        f"last time at {limit:.0%} of full torque; check the gripper for a jam and "
                        "power-cycle the servo",
                        servo_id=GRIPPER_SERVO,
                        bits=("overload",),
                    ) from e
                limit *= GRIP_LIMIT_BACKOFF
                faults.clear(GRIPPER_SERVO, "overload")
                faults.mark_clear(GRIPPER_SERVO)
                faults.emit(
                    "gripper_overload_recovered",
                    f"servo/{GRIPPER_SERVO}",
                    servo_id=GRIPPER_SERVO,
                    grip_limit=limit,
                )
                await self._world.clock.sleep(TICK_S)

    async def _close(self, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        self._world.check_bus(_GRIPPER)
        contact = self._world.contact_aperture_m()
        if contact is None or contact <= min_aperture_m:
            await self._move_to(min_aperture_m)
            return GraspResult(False, self._world.pad_force_n(), self._world.aperture_m, "closed on nothing")
        target = contact - force_threshold_n / 2000.0 * 1.5
        await self._move_to(max(min_aperture_m, target))
        force = self._world.pad_force_n()
        if force < force_threshold_n:
            return GraspResult(False, force, self._world.aperture_m, "force stayed under the threshold")
        return GraspResult(True, force, self._world.aperture_m)

    async def stop(self) -> None:
        self._world.check_bus(_GRIPPER)

    async def _move_to(self, aperture_m: float) -> None:
        clock = self._world.clock
        while self._world.aperture_m != aperture_m:
            step = JAW_SPEED_M_S * TICK_S
            delta = aperture_m - self._world.aperture_m
            self._world.aperture_m = (
                aperture_m
                if abs(delta) <= step
                else self._world.aperture_m + step * (1.0 if delta > 0 else -1.0)
            )
            await clock.sleep(TICK_S)
            self._world.check_bus(_GRIPPER)


_GRIPPER = (GRIPPER_SERVO,)


class SimForceSensor:
    """The FSR in the pad: the world's pad force, with a debounced ``holding``.

    Its faults (``world.faults``) act as on the FSR reader: while the Arduino is silent or unplugged the
    last reading and ``holding`` stand still; a dropped force reads zero; a spike is one raw sample that the
    reader's median filter keeps out of the force."""

    def __init__(self, world: KinematicWorld, *, holding_threshold_n: float) -> None:
        self._world = world
        self._threshold = holding_threshold_n
        self._seq = 0
        self._last: ForceReading | None = None
        self._holding = False

    def latest(self) -> ForceReading | None:
        if self._away():
            return self._last
        self._seq += 1
        force = self._force_n()
        raw = min(1023, int(force * FSR_COUNTS_PER_N))
        faults = self._world.faults
        if faults.fsr_spikes:
            raw = min(1023, max(0, int(faults.fsr_spikes.pop(0) * FSR_COUNTS_PER_N)))
            faults.fsr_spikes_seen += 1
        self._last = ForceReading(t=self._world.clock.now(), force_n=force, raw=raw, seq=self._seq)
        return self._last

    def holding(self) -> bool:
        if not self._away():
            self._holding = self._force_n() >= self._threshold
        return self._holding

    def _force_n(self) -> float:
        return 0.0 if self._world.faults.fsr_dropped else self._world.pad_force_n()

    def _away(self) -> bool:
        last = self._last
        age = self._world.clock.now() - last.t if last is not None else 0.0
        return self._world.faults.fsr_away(age_s=age)


def _with_travel_to_start(
    q: FloatArray, trajectory: JointTrajectory, speed: float
) -> tuple[FloatArray, FloatArray]:
    times = np.asarray(trajectory.times, dtype=np.float64)
    positions = np.asarray(trajectory.positions, dtype=np.float64)
    gap = float(np.max(np.abs(positions[0] - q)))
    if gap < 1e-6:
        return times, positions
    travel = gap / speed
    return np.concatenate([[0.0], times + travel]), np.vstack([q, positions])


def _retime(times: FloatArray, positions: FloatArray, speed: float) -> FloatArray:
    """Stretch each segment that would need more than ``speed`` on some joint."""
    dt = np.diff(times)
    dq = np.abs(np.diff(positions, axis=0)).max(axis=1)
    return np.concatenate([[0.0], np.cumsum(np.maximum(dt, dq / speed))])


def _interpolate(times: FloatArray, positions: FloatArray, t: float) -> FloatArray:
    return np.array([np.interp(t, times, positions[:, j]) for j in range(positions.shape[1])])
