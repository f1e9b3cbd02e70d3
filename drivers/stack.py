"""The robot's device stack, built one way for the real arm and for the simulated cell.

``open_device_stack`` opens the FSR reader, the servo chain (every id and model verified before any torque),
the arm's five joints and the gripper, on whatever serial ports it is given: ``/dev/dishbot-servos`` and
``/dev/dishbot-fsr`` on the robot, the simulators of ``drivers.sim`` (in-process, or on pseudo-terminals) in
the simulated cell. The daemon's hardware backend and ``sim.mujoco.cell.start_sim_cell`` both call it, so
the simulation exercises the exact stack the robot runs, on the clock it is given.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from description.arm import JOINT_LIMITS, GripperGeometry
from drivers.dynamixel import (
    BusConfig,
    DeviceEvent,
    DynamixelArm,
    DynamixelGripper,
    GripperSpec,
    JointSpec,
    ServoChain,
    tables,
)
from drivers.dynamixel.config import HealthLimits
from drivers.dynamixel.health import ChainHealth
from drivers.fsr.reader import FsrReader
from drivers.fsr.settings import FsrSettings
from drivers.interfaces import Clock
from drivers.serial_port import OpenSerial, open_pyserial

ARM_JOINTS = ("shoulder_turn", "shoulder_lift", "elbow_lift", "wrist_lift", "wrist_turn")


@dataclass(frozen=True, slots=True)
class StackSpec:
    """Everything the device stack needs: the bus, the arm joints (ids, models, limits), the gripper, the FSR,
    and the bus's retry policy."""

    bus: BusConfig
    joints: tuple[JointSpec, ...]
    gripper: GripperSpec
    fsr: FsrSettings
    retries: int = 2
    read_timeout_s: float = 0.02
    # The servos' supply and temperature limits, and when the bus calls their answers too corrupt.
    health: HealthLimits = field(default_factory=HealthLimits)
    # How the ports are opened: None is pyserial on the device files (the robot, pseudo-terminals); an
    # in-process simulator's opener carries the same bytes without a tty.
    open_bus: OpenSerial | None = None
    open_fsr: OpenSerial | None = None
    # Bus transactions on the event loop's thread: only for an in-process cable on a simulated clock
    # (``drivers.dynamixel.chain``).
    inline_bus: bool = False

    @property
    def chain(self) -> tuple[tuple[int, str], ...]:
        """Every (servo id, model) expected on the bus: the joints, then the gripper."""
        return (*((j.servo_id, j.model) for j in self.joints), (self.gripper.servo_id, self.gripper.model))


@dataclass(frozen=True, slots=True)
class DeviceStack:
    """The open devices: what a daemon backend's ``arm``, ``gripper`` and ``force`` are, and the chain's
    health (polled by the daemon, cleared on reset)."""

    chain: ServoChain
    arm: DynamixelArm
    gripper: DynamixelGripper
    force: FsrReader
    health: ChainHealth


def arm_joints(servos: Sequence[tuple[str, int, str]]) -> tuple[JointSpec, ...]:
    """The five arm joints from (name, servo id, model), limited to the URDF's joint limits kept inside each
    servo's encoder range (the AX-12A's 1023 ticks end 5 mrad short of the +150° the URDF allows)."""
    names = tuple(name for name, _, _ in servos)
    if names != ARM_JOINTS:
        raise ValueError(
            f"the arm joints must be {', '.join(ARM_JOINTS)} in that order, got {', '.join(names)}"
        )
    joints = []
    for name, servo_id, model_name in servos:
        servo = tables.model(model_name)
        lo, hi = servo.rad_from_ticks(0), servo.rad_from_ticks(servo.max_tick)
        limit = JOINT_LIMITS[name]
        joints.append(
            JointSpec(name, servo_id, model_name, max(limit.lower_rad, lo), min(limit.upper_rad, hi))
        )
    return tuple(joints)


# The gripper's aperture map for the driver: the planner's finger geometry sampled over the finger's swing.
_APERTURE_SAMPLES = 12


def gripper_spec(geometry: GripperGeometry, *, servo_id: int = 6) -> GripperSpec:
    """The driver's view of the gripper modelled by ``geometry``: angle-to-aperture from the same geometry as
    the URDF (the simulated gripper, and the real one until its map is measured)."""
    limit = JOINT_LIMITS["gripper"]
    angles = np.linspace(limit.lower_rad, limit.upper_rad, _APERTURE_SAMPLES)
    aperture_map = tuple((float(a), float(geometry.aperture_m(float(a)))) for a in angles)
    return GripperSpec(
        servo_id=servo_id,
        aperture_map=aperture_map,
        open_aperture_m=float(geometry.aperture_m(limit.lower_rad)),
    )


async def open_device_stack(
    spec: StackSpec,
    stack: contextlib.AsyncExitStack,
    *,
    clock: Clock,
    on_event: Callable[[DeviceEvent], None] | None = None,
) -> DeviceStack:
    """Open the FSR reader, the verified chain, the arm and the gripper on ``clock``, each entered on
    ``stack`` (closing it turns the torque off and closes the ports, in reverse order).
    ``on_event`` receives every device fault and recovery on the event loop. Call it on the loop that will
    use the devices."""
    fsr = spec.fsr
    force = await stack.enter_async_context(
        FsrReader(
            fsr.port,
            clock=clock,
            open_serial=spec.open_fsr or open_pyserial,
            threshold_n=fsr.threshold_n,
            release_n=fsr.release_n,
            gain=fsr.gain,
            debounce_s=fsr.debounce_s,
            stale_after_s=fsr.stale_after_s,
            on_event=on_event,
        )
    )
    chain = await stack.enter_async_context(
        ServoChain(
            spec.bus,
            spec.chain,
            clock=clock,
            retries=spec.retries,
            read_timeout_s=spec.read_timeout_s,
            corrupt_rate_max=spec.health.corrupt_rate_max,
            corrupt_window=spec.health.corrupt_window,
            on_event=on_event,
            open_serial=spec.open_bus,
            inline=spec.inline_bus,
        )
    )
    arm = await stack.enter_async_context(DynamixelArm(chain, spec.joints))
    gripper = await stack.enter_async_context(DynamixelGripper(chain, spec.gripper, force))
    return DeviceStack(
        chain=chain, arm=arm, gripper=gripper, force=force, health=ChainHealth(chain, spec.health)
    )


__all__ = [
    "ARM_JOINTS",
    "DeviceStack",
    "FsrSettings",
    "HealthLimits",
    "StackSpec",
    "arm_joints",
    "gripper_spec",
    "open_device_stack",
]
