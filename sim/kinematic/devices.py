"""What the kinematic cell's device simulators move: the servo chain's plant and the FSR's force, over the
world.

The kinematic cell runs the devices the MuJoCo cell runs — the byte-level Dynamixel chain and FSR Arduino
simulators of ``drivers.sim`` behind the real drivers — over a world without dynamics. ``KinematicPlant`` is
the chain's ``drivers.sim.plant.ServoPlant``: each servo goes to its goal at its commanded speed (capped at
the servo's no-load speed, as in the MuJoCo cell), with no inertia and no gravity, and torque off leaves it
where it is. The five arm servos move the world's joints; the gripper servo moves the jaw, whose pads squeeze
a mug they close on (the FSR simulator reads that squeeze through ``force_n``).

The jaw meets a mug as the world decides (``KinematicWorld.contact_aperture_m``) once per close, when it
has closed to the widest brim of the world's mug types; the mug is released when the jaw opens past it, and
falls out when the gripper servo's torque goes off. Positions advance lazily on the clock: whenever the chain
or the FSR simulator asks, the plant first moves every servo by the time passed since it last moved.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence

from description.arm import JOINT_LIMITS, GripperGeometry
from drivers.interfaces import Clock
from sim.kinematic.world import KinematicWorld

_EPS_M = 1e-9


class KinematicPlant:
    """The servo chain's plant over ``world``: ``arm_servos`` maps each arm servo id to its joint's name (in
    the world's arm model), ``gripper_servo`` is the jaw's; ``max_speed_rad_s`` is each servo's top speed
    (by id; a goal asking for more, or for "as fast as it can", moves at it).
    Thread-safe (a chain served from the bus thread and the FSR task on the loop may both ask)."""

    def __init__(
        self,
        world: KinematicWorld,
        *,
        arm_servos: Sequence[tuple[int, str]],
        gripper_servo: int,
        gripper: GripperGeometry,
        clock: Clock,
        max_speed_rad_s: Mapping[int, float],
    ) -> None:
        names = world.arm.joint_names
        unknown = [name for _, name in arm_servos if name not in names]
        if unknown:
            raise ValueError(f"joints {unknown} are not in the arm model's {names}")
        self._world = world
        self._geometry = gripper
        self._clock = clock
        self._ids = [servo_id for servo_id, _ in arm_servos] + [gripper_servo]
        self._max_speed = [max_speed_rad_s[servo_id] for servo_id in self._ids]
        self._index = {servo_id: k for k, servo_id in enumerate(self._ids)}
        self._joint = [names.index(name) for _, name in arm_servos]  # world joint of each arm servo
        self._gripper = len(arm_servos)
        q = [float(world.q[j]) for j in self._joint]
        jaw = JOINT_LIMITS["gripper"]
        opening = min(
            max(world.aperture_m, gripper.aperture_m(jaw.upper_rad)), gripper.aperture_m(jaw.lower_rad)
        )
        world.aperture_m = opening  # the jaw as the gripper's geometry allows it
        self._pos = [*q, gripper.angle_for_aperture(opening)]
        self._goal = list(self._pos)
        self._speed = list(self._max_speed)
        self._vel = [0.0] * len(self._pos)
        self._torque = [False] * len(self._pos)
        self._last = clock.monotonic()
        self._checked_contact = False  # the jaw has asked the world what it closes on since it last opened
        self._lock = threading.Lock()

    # --- ServoPlant ------------------------------------------------------------------------------------

    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None:
        with self._lock:
            self._advance()
            k = self._k(servo_id)
            self._goal[k] = position_rad
            top = self._max_speed[k]
            speed = top if speed_rad_s <= 0.0 else min(speed_rad_s, top)
            self._speed[k] = max(speed, 1e-3)

    def present(self, servo_id: int) -> tuple[float, float, float]:
        with self._lock:
            self._advance()
            k = self._k(servo_id)
            load = max(-1.0, min(1.0, (self._goal[k] - self._pos[k]) * 2.0)) if self._torque[k] else 0.0
            return self._pos[k], self._vel[k], load

    def set_torque(self, servo_id: int, on: bool) -> None:
        with self._lock:
            self._advance()
            k = self._k(servo_id)
            self._torque[k] = on
            self._vel[k] = 0.0
            if on:
                self._goal[k] = self._pos[k]
            elif k == self._gripper and self._world.held is not None:
                # The jaw goes limp: the carried mug falls where it is, and the next close looks again.
                self._world.drop_held_mug()
                self._checked_contact = False

    def follow_world(self) -> None:
        """Take the servos' positions from the world as it is now (after ``KinematicWorld.restage``): every
        servo at rest where the world's joints and jaw are, its goal there, its torque as it was; a jaw
        holding a mug has met it already. Without this the next step would move the world back to where
        the servos were."""
        with self._lock:
            world = self._world
            self._last = self._clock.monotonic()
            for k, j in enumerate(self._joint):
                self._pos[k] = float(world.q[j])
            self._pos[self._gripper] = self._geometry.angle_for_aperture(world.aperture_m)
            self._goal = list(self._pos)
            self._vel = [0.0] * len(self._pos)
            self._checked_contact = world.held is not None

    # --- the FSR simulator's force source ---------------------------------------------------------------

    def force_n(self) -> float:
        """The pads' squeeze on the mug between them, now."""
        with self._lock:
            self._advance()
            return self._world.pad_force_n()

    # --- motion -----------------------------------------------------------------------------------------

    def _k(self, servo_id: int) -> int:
        try:
            return self._index[servo_id]
        except KeyError:
            known = ", ".join(map(str, self._ids))
            raise KeyError(f"no servo with id {servo_id} in the kinematic arm (ids: {known})") from None

    def _advance(self) -> None:
        now = self._clock.monotonic()
        dt = now - self._last
        if dt <= 0.0:
            return
        self._last = now
        pos, goal, vel = self._pos, self._goal, self._vel
        moved_arm = False
        old_jaw = pos[self._gripper]
        for k in range(len(pos)):
            if not self._torque[k]:
                vel[k] = 0.0
                continue
            error = goal[k] - pos[k]
            if error == 0.0:
                vel[k] = 0.0
                continue
            step = self._speed[k] * dt
            new = goal[k] if abs(error) <= step else pos[k] + (step if error > 0 else -step)
            vel[k] = (new - pos[k]) / dt
            pos[k] = new
            moved_arm = moved_arm or k != self._gripper
        world = self._world
        if moved_arm:
            q = world.q.copy()
            for k, j in enumerate(self._joint):
                q[j] = pos[k]
            world.set_q(q)
        if pos[self._gripper] != old_jaw:
            self._move_jaw(old_jaw, pos[self._gripper])

    def _move_jaw(self, old_rad: float, new_rad: float) -> None:
        world = self._world
        before = world.aperture_m
        world.aperture_m = self._geometry.aperture_m(new_rad)
        closing = world.aperture_m < before - _EPS_M
        if closing and not self._checked_contact and world.held is None and world.aperture_m < self._widest():
            # The pads can touch a brim now: take the mug between them, if there is one (once per close).
            self._checked_contact = True
            world.contact_aperture_m()
        elif world.aperture_m > before + _EPS_M:
            self._checked_contact = False
            held = world.held
            if held is not None and world.aperture_m >= world.mug_geometry[world.mugs[held].type].diameter_m:
                world.release()

    def _widest(self) -> float:
        """The widest brim of the world's mug types: a jaw opened wider touches no mug."""
        return max((g.diameter_m for g in self._world.mug_geometry.values()), default=0.0)
