"""Where a fault file's faults act in each simulated cell (``replay.faults.Cell``).

The MuJoCo cell runs the real Dynamixel and FSR drivers against the byte-level device simulators, so its
device faults are the simulators' own hooks (error bits and registers set as the firmware sets them, a
silent servo, corrupt packets, a pulled adapter, a quiet Arduino); its camera is the ``FaultyCamera`` its
observer looks through; the mugs are the physics world's. The kinematic cell's devices carry their faults
themselves (``sim.kinematic.faults``, raising what the drivers raise) and its observer the camera's.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from daemon.sim_backend import KinematicCounter, MujocoCounter
from drivers.sim.camera import CameraFault
from replay.faults import CAMERA_KINDS, FaultSpec

End = Callable[[], None]
Acted = tuple[End | None, dict[str, object]]


def _camera_fault(kind: str) -> CameraFault:
    return CAMERA_KINDS[kind]


class KinematicFaultCell:
    """Faults of the kinematic cell: its devices' fault state, its observer, its world."""

    name = "kinematic"

    def __init__(self, counter: KinematicCounter) -> None:
        self._counter = counter

    def servo_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._counter.cell.world.faults.servos))

    def act(self, spec: FaultSpec) -> Acted:
        world = self._counter.cell.world
        faults = world.faults
        kind, servo, lasting = spec.kind, spec.servo, spec.duration_s is not None
        if kind in ("servo_overload", "servo_overheat"):
            assert servo is not None
            name = "overload" if kind == "servo_overload" else "overheating"
            faults.trip(servo, name, lasting=lasting)
            if not lasting:
                faults.end(servo, name)  # the cause is gone at once; the bit stays latched until cleared
                return None, {"servo": servo}
            return (lambda: faults.end(servo, name)), {"servo": servo}
        if kind == "servo_voltage":
            assert servo is not None
            faults.brown_out(servo)
            return (lambda: faults.brown_out(servo, on=False)), {"servo": servo}
        if kind == "servo_silent":
            assert servo is not None
            faults.silence(servo)
            return (lambda: faults.silence(servo, on=False)), {"servo": servo}
        if kind == "bus_corrupt":
            assert spec.rate is not None
            faults.corrupt_fraction(spec.rate, seed=spec.seed or 0, servo_id=servo)
            return (lambda: faults.corrupt_fraction(0.0)), _bus_target(spec)
        if kind == "bus_unplug":
            if spec.device == "fsr":
                faults.fsr_unplugged = True
                return (lambda: setattr(faults, "fsr_unplugged", False)), {"device": "fsr"}
            faults.unplug_bus()
            return (lambda: faults.unplug_bus(False)), {"device": "servo"}
        if kind == "fsr_drop":
            faults.fsr_dropped = True
            return (lambda: setattr(faults, "fsr_dropped", False)), {}
        if kind == "fsr_spike":
            faults.fsr_spikes.append(spec.value_n or 0.0)
            return None, {"value_n": spec.value_n}
        if kind == "fsr_silent":
            faults.fsr_silent = True
            return (lambda: setattr(faults, "fsr_silent", False)), {}
        if kind in CAMERA_KINDS:
            observer = self._counter.observer
            assert observer is not None
            observer.set_fault(_camera_fault(kind))
            return observer.clear, {}
        if kind == "mug_slip":
            return None, {"mug": world.drop_held_mug()}
        if kind == "mug_moved":
            mug = spec.mug or self._farthest_counter_mug()
            if mug is None:
                return None, {"mug": None}
            try:
                world.move_mug(mug, spec.dx_m or 0.0, spec.dy_m or 0.0)
            except ValueError as e:
                return None, {"mug": mug, "error": str(e)}
            return None, {"mug": mug, "dx_m": spec.dx_m, "dy_m": spec.dy_m}
        raise AssertionError(f"no kinematic cell action for {kind}")

    def _farthest_counter_mug(self) -> str | None:
        world = self._counter.cell.world
        p, _ = world.grasp_pose()
        on_counter = [m for m in world.mugs.values() if m.where == "counter"]
        if not on_counter:
            return None
        return max(on_counter, key=lambda m: (math.hypot(m.x_m - p[0], m.y_m - p[1]), m.mug_id)).mug_id


class MujocoFaultCell:
    """Faults of the MuJoCo cell: its servo chain and FSR simulators, its camera, its physics world."""

    name = "mujoco"

    def __init__(self, counter: MujocoCounter) -> None:
        self._counter = counter

    def servo_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._counter.cell.servo_sim.servo_ids))

    def act(self, spec: FaultSpec) -> Acted:
        cell = self._counter.cell
        servos, fsr = cell.servo_sim, cell.fsr_sim
        kind, servo, lasting = spec.kind, spec.servo, spec.duration_s is not None
        if kind == "servo_overload":
            assert servo is not None
            if not lasting:
                servos.overload(servo)
                return None, {"servo": servo}
            servos.keep_overloaded(servo)
            return (lambda: servos.keep_overloaded(servo, on=False)), {"servo": servo}
        if kind == "servo_overheat":
            assert servo is not None
            # Hot until the fault ends (its duration, or the end of the run): the servo reports it in every
            # status meanwhile, and a reset cannot clear it (the cause is still there).
            servos.overheat(servo)
            return (lambda: servos.overheat(servo, on=False)), {"servo": servo}
        if kind == "servo_voltage":
            assert servo is not None
            servos.brown_out(servo)
            return (lambda: servos.brown_out(servo, on=False)), {"servo": servo}
        if kind == "servo_silent":
            assert servo is not None
            servos.silence(servo)
            return (lambda: servos.silence(servo, on=False)), {"servo": servo}
        if kind == "bus_corrupt":
            assert spec.rate is not None
            servos.corrupt_fraction(spec.rate, seed=spec.seed or 0, servo_id=servo)
            return (lambda: servos.corrupt_fraction(0.0)), _bus_target(spec)
        if kind == "bus_unplug":
            device = fsr if spec.device == "fsr" else servos
            device.unplug()
            return device.replug, {"device": spec.device or "servo"}
        if kind == "fsr_drop":
            fsr.drop_force(True)
            return (lambda: fsr.drop_force(False)), {}
        if kind == "fsr_spike":
            fsr.spike(spec.value_n or 0.0)
            return None, {"value_n": spec.value_n}
        if kind == "fsr_silent":
            fsr.silence(True)
            return (lambda: fsr.silence(False)), {}
        if kind in CAMERA_KINDS:
            camera = self._counter.camera
            assert camera is not None
            camera.set_fault(_camera_fault(kind))
            return camera.clear, {}
        if kind == "mug_slip":
            return None, {"mug": cell.world.slip()}
        if kind == "mug_moved":
            mug = spec.mug or self._farthest_counter_mug()
            if mug is None:
                return None, {"mug": None}
            try:
                cell.world.move_mug(mug, spec.dx_m or 0.0, spec.dy_m or 0.0)
            except ValueError as e:
                return None, {"mug": mug, "error": str(e)}
            return None, {"mug": mug, "dx_m": spec.dx_m, "dy_m": spec.dy_m}
        raise AssertionError(f"no MuJoCo cell action for {kind}")

    def _farthest_counter_mug(self) -> str | None:
        cell = self._counter.cell
        tcp = cell.world.tcp_position()
        tray = cell.layout.tray
        standing = [
            t
            for t in cell.world.mug_truths().values()
            if not t.held and t.axis_z > 0.9 and not tray.contains(t.position_m[0], t.position_m[1])
        ]
        if not standing:
            return None
        far = max(
            standing, key=lambda t: (math.hypot(t.position_m[0] - tcp[0], t.position_m[1] - tcp[1]), t.mug_id)
        )
        return far.mug_id


def _bus_target(spec: FaultSpec) -> dict[str, object]:
    target: dict[str, object] = {"rate": spec.rate}
    if spec.servo is not None:
        target["servo"] = spec.servo
    return target
