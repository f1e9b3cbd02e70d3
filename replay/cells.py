"""The devices and world of each simulated cell, as the fault dispatcher (``replay.faults``) acts on them.

One protocol (``FaultCell``) for both cells: each method sets one device's condition to what the faults
acting on it together ask (``on``/``off``, a camera's fault, a corrupt rate) or makes one thing happen once
(a trip, a spike, a slip, a move). Which faults are acting, and so what each device's condition is, is the
dispatcher's business; a cell only knows its devices.

Both cells run the real Dynamixel and FSR drivers against the same byte-level device simulators
(``sim.devices``), so one class (``SimFaultCell``) acts on either: the device faults are the simulators' own
hooks (error bits and registers set as the firmware sets them, a silent servo, corrupt packets, a pulled
adapter, a quiet Arduino), the camera's the ``FaultyCamera`` the observer looks through. Only the world
differs (``WorldFaults``): the kinematic world's mugs or the physics world's.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

from drivers.sim.camera import CameraFaultKind

if TYPE_CHECKING:
    from daemon.app import ServeContext
    from daemon.sim_backend import KinematicCounter, MujocoCounter
    from drivers.sim.fsr import FsrSimulator
    from drivers.sim.servo_chain import ServoChainSimulator


class FailingCamera(Protocol):
    """A camera whose captures can be made to fail (``drivers.sim.camera.FaultyCamera``)."""

    fault: CameraFaultKind | None

    def set_fault(self, fault: CameraFaultKind) -> None: ...

    def clear(self) -> None: ...


class FaultCell(Protocol):
    """Where faults act in one simulated cell."""

    name: str

    def servo_ids(self) -> tuple[int, ...]: ...

    def servo_overloaded(self, servo: int, *, on: bool) -> None:
        """A load the servo cannot hold, lasting: it trips whenever driven until ``on=False``."""

    def servo_trip(self, servo: int) -> None:
        """Trip the servo's overload protection once (latched until the daemon clears it)."""

    def servo_hot(self, servo: int, *, on: bool) -> None: ...

    def servo_low_voltage(self, servo: int, *, on: bool) -> None: ...

    def servo_silent(self, servo: int, *, on: bool) -> None: ...

    def bus_corrupt(self, rate: float, *, seed: int, servo: int | None) -> None:
        """Corrupt ``rate`` of the status packets (of ``servo``, or all); rate 0 stops it."""

    def unplugged(self, device: str, *, on: bool) -> None:
        """The USB adapter of ``device`` (``servo`` or ``fsr``) pulled (``on``) or plugged back."""

    def fsr_dropped(self, *, on: bool) -> None: ...

    def fsr_silent(self, *, on: bool) -> None: ...

    def fsr_spike(self, value_n: float) -> None: ...

    def camera(self) -> FailingCamera: ...

    def slip(self) -> str | None:
        """The carried mug falls out of the gripper; its world id (None: nothing was held)."""

    def counter_mugs(self) -> tuple[tuple[str, float, float], ...]:
        """The world's mugs standing on the counter (id, x, y in metres), farthest from the gripper first."""

    def move_mug(self, mug: str, dx_m: float, dy_m: float) -> None:
        """Move a counter mug; ``ValueError`` when it cannot go there."""


def set_camera_fault(camera: FailingCamera, fault: CameraFaultKind | None) -> None:
    """Make ``camera`` fail in the ``fault`` way (None: work again). A hung capture is released when the
    hang gives way to another fault, as it is when the hang ends."""
    if camera.fault == fault:
        return
    if fault is None or camera.fault == "hang":
        camera.clear()
    if fault is not None:
        camera.set_fault(fault)


class WorldFaults(Protocol):
    """The faults a cell's world takes: a slip, and where its counter mugs stand and a move of one."""

    def slip(self) -> str | None: ...

    def counter_mugs(self) -> tuple[tuple[str, float, float], ...]: ...

    def move_mug(self, mug: str, dx_m: float, dy_m: float) -> None: ...


class SimFaultCell:
    """Faults of a simulated cell: its servo chain and FSR simulators, its camera, its world."""

    def __init__(
        self,
        name: str,
        servos: ServoChainSimulator,
        fsr: FsrSimulator,
        camera: FailingCamera,
        world: WorldFaults,
    ) -> None:
        self.name = name
        self._servos = servos
        self._fsr = fsr
        self._camera = camera
        self._world = world

    def servo_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._servos.servo_ids))

    def servo_overloaded(self, servo: int, *, on: bool) -> None:
        self._servos.keep_overloaded(servo, on=on)

    def servo_trip(self, servo: int) -> None:
        self._servos.overload(servo)

    def servo_hot(self, servo: int, *, on: bool) -> None:
        self._servos.overheat(servo, on=on)

    def servo_low_voltage(self, servo: int, *, on: bool) -> None:
        self._servos.brown_out(servo, on=on)

    def servo_silent(self, servo: int, *, on: bool) -> None:
        self._servos.silence(servo, on=on)

    def bus_corrupt(self, rate: float, *, seed: int, servo: int | None) -> None:
        self._servos.corrupt_fraction(rate, seed=seed, servo_id=servo)

    def unplugged(self, device: str, *, on: bool) -> None:
        target = self._fsr if device == "fsr" else self._servos
        if on:
            target.unplug()
        else:
            target.replug()

    def fsr_dropped(self, *, on: bool) -> None:
        self._fsr.drop_force(on)

    def fsr_silent(self, *, on: bool) -> None:
        self._fsr.silence(on)

    def fsr_spike(self, value_n: float) -> None:
        self._fsr.spike(value_n)

    def camera(self) -> FailingCamera:
        return self._camera

    def slip(self) -> str | None:
        return self._world.slip()

    def counter_mugs(self) -> tuple[tuple[str, float, float], ...]:
        return self._world.counter_mugs()

    def move_mug(self, mug: str, dx_m: float, dy_m: float) -> None:
        self._world.move_mug(mug, dx_m, dy_m)


class KinematicWorldFaults:
    """The kinematic world's mugs."""

    def __init__(self, counter: KinematicCounter) -> None:
        self._world = counter.cell.world

    def slip(self) -> str | None:
        return self._world.drop_held_mug()

    def counter_mugs(self) -> tuple[tuple[str, float, float], ...]:
        world = self._world
        p, _ = world.grasp_pose()
        on_counter = [m for m in world.mugs.values() if m.where == "counter"]
        ranked = sorted(on_counter, key=lambda m: (math.hypot(m.x_m - p[0], m.y_m - p[1]), m.mug_id))
        return tuple((m.mug_id, m.x_m, m.y_m) for m in reversed(ranked))

    def move_mug(self, mug: str, dx_m: float, dy_m: float) -> None:
        self._world.move_mug(mug, dx_m, dy_m)


class MujocoWorldFaults:
    """The physics world's mugs."""

    def __init__(self, counter: MujocoCounter) -> None:
        self._cell = counter.cell

    def slip(self) -> str | None:
        return self._cell.world.slip()

    def counter_mugs(self) -> tuple[tuple[str, float, float], ...]:
        cell = self._cell
        tcp = cell.world.tcp_position()
        tray = cell.layout.tray
        standing = [
            t
            for t in cell.world.mug_truths().values()
            if not t.held and t.axis_z > 0.9 and not tray.contains(t.position_m[0], t.position_m[1])
        ]
        ranked = sorted(
            standing, key=lambda t: (math.hypot(t.position_m[0] - tcp[0], t.position_m[1] - tcp[1]), t.mug_id)
        )
        return tuple((t.mug_id, float(t.position_m[0]), float(t.position_m[1])) for t in reversed(ranked))

    def move_mug(self, mug: str, dx_m: float, dy_m: float) -> None:
        self._cell.world.move_mug(mug, dx_m, dy_m)


def cell_of(ctx: ServeContext) -> FaultCell | None:
    """Where faults act in the daemon's backend: the kinematic or the MuJoCo cell (None: real hardware)."""
    from daemon.sim_backend import KinematicCounter, MujocoCounter

    counter = ctx.backend.counter
    if isinstance(counter, KinematicCounter):
        cell = counter.cell
        return SimFaultCell(
            "kinematic", cell.servo_sim, cell.fsr_sim, cell.camera, KinematicWorldFaults(counter)
        )
    if isinstance(counter, MujocoCounter):
        camera = counter.camera
        assert camera is not None
        sim = counter.cell
        return SimFaultCell("mujoco", sim.servo_sim, sim.fsr_sim, camera, MujocoWorldFaults(counter))
    return None
