"""What moves behind the simulated servos: the ``ServoPlant`` seam and a first-order default.

The pseudo-terminal chain asks its plant where each servo is whenever the host reads a present-state
register, and tells it every new goal and torque change. The MuJoCo world implements the same protocol so
the simulated cell moves through exactly the bytes a real arm would receive. Plants are called from the
simulator's serving thread and must be thread-safe.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable


class PlantStopped(RuntimeError):
    """The physical side of the servos is gone (its simulation died): they answer nothing from then on, as
    servos whose power was cut."""


@runtime_checkable
class ServoPlant(Protocol):
    """The physical side of a servo chain, addressed by servo id; radians and rad/s."""

    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None: ...

    def present(self, servo_id: int) -> tuple[float, float, float]:
        """(position_rad, velocity_rad_s, load as a signed fraction of full torque); ``PlantStopped`` once
        the plant is gone."""
        ...

    def set_torque(self, servo_id: int, on: bool) -> None: ...


@dataclass(slots=True)
class _Joint:
    position: float = 0.0
    goal: float = 0.0
    speed: float = math.pi
    velocity: float = 0.0
    torque: bool = False


class FirstOrderPlant:
    """Each servo approaches its goal with time constant ``tau_s``, never faster than the commanded speed.

    Torque off freezes the joint where it is (no gravity). ``load`` rises with the remaining error, like a
    position-controlled servo pushing towards its goal, saturating at 1. ``clock`` gives the time it moves
    in (a ``Clock``'s ``monotonic``).
    """

    def __init__(
        self,
        initial_rad: Mapping[int, float] | None = None,
        *,
        clock: Callable[[], float],
        tau_s: float = 0.05,
    ) -> None:
        self._joints = {sid: _Joint(position=q, goal=q) for sid, q in (initial_rad or {}).items()}
        self._tau = tau_s
        self._clock = clock
        self._last = clock()
        self._lock = threading.Lock()

    def _joint(self, servo_id: int) -> _Joint:
        return self._joints.setdefault(servo_id, _Joint())

    def _advance(self) -> None:
        now = self._clock()
        dt, self._last = now - self._last, now
        if dt <= 0:
            return
        for joint in self._joints.values():
            if not joint.torque:
                joint.velocity = 0.0
                continue
            error = joint.goal - joint.position
            velocity = max(-joint.speed, min(joint.speed, error / self._tau))
            step = velocity * dt
            joint.position = joint.goal if abs(step) >= abs(error) else joint.position + step
            joint.velocity = velocity

    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None:
        with self._lock:
            self._advance()
            joint = self._joint(servo_id)
            joint.goal = position_rad
            joint.speed = max(abs(speed_rad_s), 1e-3)

    def set_torque(self, servo_id: int, on: bool) -> None:
        with self._lock:
            self._advance()
            joint = self._joint(servo_id)
            joint.torque = on
            if on:
                joint.goal = joint.position

    def present(self, servo_id: int) -> tuple[float, float, float]:
        with self._lock:
            self._advance()
            joint = self._joint(servo_id)
            load = max(-1.0, min(1.0, (joint.goal - joint.position) * 2.0)) if joint.torque else 0.0
            return joint.position, joint.velocity, load
