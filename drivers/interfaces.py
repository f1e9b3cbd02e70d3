"""The seams between the daemon and the devices: what an arm, a gripper, a force sensor and a camera offer.

The statechart and the daemon depend only on these protocols. Real hardware (Dynamixel bus, Arduino FSR,
depth camera) and the simulated cell implement them; nothing above ``drivers/`` imports a vendor SDK.
Angles are radians, lengths metres, forces newtons, times seconds (the ``Clock``'s monotonic time unless
stated).

Time is a seam too: every driver, the job, the telemetry, the device simulators and the recorder read and
wait on the ``Clock`` they were constructed with, never on the wall clock. The daemon chooses the clock
(``daemon.clock``): the wall clock on the robot, a simulated clock in the simulated cell, which may run
faster than real time and is advanced by the simulated world.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from description.arrays import FloatArray
from description.camera import CameraIntrinsics

__all__ = ["CameraIntrinsics", "FloatArray"]  # re-exported: the camera protocol speaks them


@runtime_checkable
class Clock(Protocol):
    """Where time comes from: what deadlines, periods and ages are measured on, and what published and
    recorded messages are stamped with.

    The event loop the coroutines run on keeps the same time (``loop.time() == monotonic()``), so asyncio's
    own timeouts agree with it; still, code waits through the clock, never on the wall clock behind it."""

    @property
    def simulated(self) -> bool:
        """True when time is the simulation's (it may run faster than real time, or stand still)."""
        ...

    def monotonic(self) -> float:
        """Seconds on a clock that never jumps back: deadlines, periods, ages, ``t_device``."""
        ...

    def now(self) -> float:
        """Unix seconds, the ``t`` of what is published and recorded. In simulation: the wall-clock start of
        the session plus the simulated time since, so a recording does not depend on the machine's load."""
        ...

    async def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of this clock's time (0 or less: just yield)."""
        ...

    async def sleep_until(self, t: float) -> None:
        """Wait until ``monotonic()`` reaches ``t``; periodic loops use it so that they never drift."""
        ...

    def timeout(self, seconds: float | None) -> AbstractAsyncContextManager[object]:
        """``async with clock.timeout(s):`` raises ``TimeoutError`` when the block takes longer than ``s``
        (None: no limit)."""
        ...

    async def wait(self, future: asyncio.Future[Any], seconds: float | None) -> bool:
        """Wait until ``future`` is done or ``seconds`` passed (None: no limit), without cancelling it;
        whether it is done."""
        ...


@runtime_checkable
class SteppedClock(Clock, Protocol):
    """A simulated clock that advances the simulated world itself: each stepper is called with the new
    ``monotonic()`` time whenever time moves forward, on the event loop's thread, before any task sees the
    new time, while no driver is talking to a device. A world stepped this way is in lockstep with every
    reader of the clock, however loaded the machine is."""

    def add_stepper(self, step: Callable[[float], None]) -> Callable[[], None]:
        """Call ``step(t)`` on every advance of time; returns the function that removes it again."""
        ...


@dataclass(frozen=True, slots=True)
class JointState:
    """Present position, velocity and load of every arm joint (gripper excluded), in chain order."""

    t: float
    names: tuple[str, ...]
    position_rad: tuple[float, ...]
    velocity_rad_s: tuple[float, ...]
    load: tuple[float, ...]  # signed fraction of the servo's torque limit, -1..1


@dataclass(frozen=True, slots=True)
class JointTrajectory:
    """A time-parameterised joint-space path: ``positions[i]`` is reached at ``times[i]`` (from 0)."""

    names: tuple[str, ...]
    times: FloatArray  # shape (n,), non-decreasing, times[0] == 0
    positions: FloatArray  # shape (n, len(names)), radians
    label: str = ""

    @property
    def duration(self) -> float:
        return float(self.times[-1]) if len(self.times) else 0.0


@dataclass(frozen=True, slots=True)
class GripperState:
    """What the gripper knows about itself: opening and the servo's load."""

    t: float
    aperture_m: float
    load: float


@dataclass(frozen=True, slots=True)
class ForceReading:
    """One force-sensing-resistor sample from the gripper pad."""

    t: float
    force_n: float
    raw: int  # ADC counts as the microcontroller read them
    seq: int


@dataclass(frozen=True, slots=True)
class GraspResult:
    """Outcome of closing the gripper on a mug: held when the force passed the threshold in time."""

    held: bool
    force_n: float
    aperture_m: float
    reason: str = ""


@dataclass(frozen=True, slots=True)
class RGBDFrame:
    """One depth frame (metres, 0 = no reading), an optional colour image, and where the camera was."""

    t: float
    depth_m: npt.NDArray[np.float32]  # (height, width)
    intrinsics: CameraIntrinsics
    world_from_camera: FloatArray  # (4, 4)
    color: npt.NDArray[np.uint8] | None = None  # (height, width, 3) RGB
    meta: dict[str, str] = field(default_factory=dict)


@runtime_checkable
class ArmDriver(Protocol):
    """The arm's joints (without the gripper)."""

    @property
    def joint_names(self) -> tuple[str, ...]: ...

    async def read_joints(self) -> JointState:
        """Latest joint state; raises a ``drivers.errors.DriverError`` subclass when the bus fails."""
        ...

    async def follow(self, trajectory: JointTrajectory) -> None:
        """Execute a trajectory and return once it is done. Cancelling stops the arm where it is."""
        ...

    async def stop(self) -> None:
        """Hold the present position now (used on pause, fault and cancellation)."""
        ...

    async def relax(self) -> None:
        """Torque off (used on e-stop and shutdown after parking)."""
        ...


@runtime_checkable
class GripperDriver(Protocol):
    """The gripper servo."""

    async def read(self) -> GripperState: ...

    async def open(self, aperture_m: float | None = None) -> None:
        """Open to ``aperture_m`` between the pads (at most fully, and never closing: a wider jaw stays as
        it is), or fully when None, and return once there. Opening only a little wider than the mug lets go
        of it between close neighbours without the finger swinging into them."""
        ...

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        """Close until the force sensor passes the threshold; not held when the aperture gets too small."""
        ...

    async def stop(self) -> None: ...


@runtime_checkable
class ForceSensor(Protocol):
    """The FSR in the gripper pad."""

    def latest(self) -> ForceReading | None:
        """Newest sample, or None before the first one arrived. Never blocks."""
        ...

    def holding(self) -> bool:
        """True while the debounced force says a mug is in the gripper."""
        ...


@runtime_checkable
class DeviceHealth(Protocol):
    """The devices' own health: polled for slow dangers (supply voltage, temperature), asked before a
    start, and cleared on reset."""

    @property
    def poll_period_s(self) -> float: ...

    async def poll(self) -> None:
        """Look at every device once and report what changed; raises a ``drivers.errors.DriverError``
        subclass (or ``BusLost``) while a device is past a limit or unreachable."""
        ...

    def problems(self) -> tuple[str, ...]:
        """What stands against a start now, one line each (empty: nothing); never blocks."""
        ...

    async def clear(self) -> tuple[str, ...]:
        """Clear every device's fault that can be cleared (reset); what still stands, one line each."""
        ...


@runtime_checkable
class Camera(Protocol):
    """An RGB-D camera."""

    async def capture(self) -> RGBDFrame: ...


def joint_vector(values: Sequence[float]) -> FloatArray:
    """A float64 copy of a joint vector, for arithmetic on positions."""
    return np.asarray(values, dtype=np.float64).copy()
