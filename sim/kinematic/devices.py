"""The kinematic cell's arm, gripper and force sensor: the ``drivers.interfaces`` protocols over the world."""

from __future__ import annotations

import numpy as np

from drivers.errors import LimitViolation
from drivers.interfaces import (
    FloatArray,
    ForceReading,
    GraspResult,
    GripperState,
    JointState,
    JointTrajectory,
)
from sim.kinematic.world import JAW_SPEED_M_S, OPEN_APERTURE_M, KinematicWorld

TICK_S = 0.01  # period (on the world's clock) at which a moving device updates the world
FSR_COUNTS_PER_N = 40.0  # ADC counts per newton of the simulated FSR (saturates at 1023)


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
        self._world.check_bus()
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
        self._world.check_bus()
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
            self._world.check_bus()

    async def stop(self) -> None:
        # Positions are only ever set to where the arm is, so holding still needs no command.
        self._world.check_bus()

    async def relax(self) -> None:
        self._world.check_bus()


class SimGripper:
    """A jaw that closes at finite speed; its pad force rises once it squeezes a mug."""

    def __init__(self, world: KinematicWorld) -> None:
        self._world = world

    async def read(self) -> GripperState:
        self._world.check_bus()
        return GripperState(
            t=self._world.clock.now(),
            aperture_m=self._world.aperture_m,
            load=min(1.0, self._world.pad_force_n() / 20.0),
        )

    async def open(self, aperture_m: float | None = None) -> None:
        self._world.check_bus()
        self._world.release()
        target = OPEN_APERTURE_M if aperture_m is None else min(aperture_m, OPEN_APERTURE_M)
        await self._move_to(max(target, self._world.aperture_m))

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        self._world.check_bus()
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
        self._world.check_bus()

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
            self._world.check_bus()


class SimForceSensor:
    """The FSR in the pad: the world's pad force, with a debounced ``holding``."""

    def __init__(self, world: KinematicWorld, *, holding_threshold_n: float) -> None:
        self._world = world
        self._threshold = holding_threshold_n
        self._seq = 0

    def latest(self) -> ForceReading | None:
        self._seq += 1
        force = self._world.pad_force_n()
        raw = min(1023, int(force * FSR_COUNTS_PER_N))
        return ForceReading(t=self._world.clock.now(), force_n=force, raw=raw, seq=self._seq)

    def holding(self) -> bool:
        return self._world.pad_force_n() >= self._threshold


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
