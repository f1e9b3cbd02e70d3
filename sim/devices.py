"""The simulated cells' devices: the byte-level device simulators behind the real drivers, one way for both.

Both worlds, the kinematic one and the MuJoCo one, put the same devices in front of the daemon:
``open_cell_devices`` starts the simulated Dynamixel chain (``drivers.sim.ServoChainSimulator``) with the
world as its plant and the simulated FSR Arduino (``drivers.sim.FsrSimulator``) fed by the world's pad force,
then opens the robot's own device stack on them (``drivers.stack.open_device_stack``: dynamixel-sdk, the arm,
the gripper, the FSR reader, the chain's health). So every device fault (the simulators' hooks: error bits and
registers as the firmware sets them, a silent servo, corrupt packets, a pulled adapter, a quiet Arduino) acts
through the same bytes and drivers in either world, and is met as on the robot.

On the in-process transport and a simulated clock the bus transactions run inline on the event loop's thread
(``ServoChain(inline=True)``): no thread hop, and no simulated time while every servo answers; a transaction
that waits on a servo (a silent one, a lost or garbled answer) waits its status timeouts in simulated time,
as on the robot. On a pseudo-terminal the devices are served by their own threads in wall-clock time.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

from description.arm import GripperGeometry
from description.thesis import JOINT_SERVOS
from drivers.dynamixel import BusConfig, DeviceEvent
from drivers.dynamixel.health import HealthLimits
from drivers.interfaces import Clock
from drivers.sim.fsr import FsrSimulator
from drivers.sim.plant import ServoPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from drivers.stack import (
    ARM_JOINTS,
    DeviceStack,
    FsrSettings,
    StackSpec,
    arm_joints,
    gripper_spec,
    open_device_stack,
)

TRANSPORTS = ("inprocess", "pty")
GRIPPER_SERVO = len(ARM_JOINTS) + 1  # the chain's ids: the arm joints 1-5 in order, then the gripper


def arm_servos() -> tuple[tuple[int, str], ...]:
    """(servo id, joint name) of the arm's five joint servos, as the chain numbers them."""
    return tuple((i + 1, joint) for i, joint in enumerate(ARM_JOINTS))


@dataclass(frozen=True, slots=True)
class CellDevices:
    """The device simulators (their fault hooks) and the real drivers opened on them."""

    servo_sim: ServoChainSimulator
    fsr_sim: FsrSimulator
    stack: DeviceStack


async def open_cell_devices(
    plant: ServoPlant,
    force_n: Callable[[], float],
    *,
    gripper: GripperGeometry,
    clock: Clock,
    transport: str,
    stack: contextlib.AsyncExitStack,
    on_event: Callable[[DeviceEvent], None],
    holding_threshold_n: float,
    fsr_debounce_s: float,
    health: HealthLimits | None = None,
) -> CellDevices:
    """Start the servo chain simulator on ``plant`` and the FSR simulator on ``force_n`` (``transport``
    ``"inprocess"`` on ``clock``, or ``"pty"``), and open the device stack on them; everything is entered on
    ``stack``. ``on_event`` gets every fault and recovery the drivers report, on the event loop. Call it on
    the event loop that will use the devices."""
    if transport not in TRANSPORTS:
        raise ValueError(f"transport {transport!r}: choose one of {', '.join(TRANSPORTS)}")
    servo_sim = ServoChainSimulator(default_chain(), plant=plant)
    fsr_sim = FsrSimulator(force_n)
    for device in (servo_sim, fsr_sim):
        if transport == "pty":
            device.start()
        else:
            device.start_in_process(clock)
        stack.callback(device.stop)
    models = dict(JOINT_SERVOS)
    spec = StackSpec(
        bus=BusConfig(servo_sim.device_path),
        joints=arm_joints([(joint, servo_id, models[joint]) for servo_id, joint in arm_servos()]),
        gripper=gripper_spec(gripper, servo_id=GRIPPER_SERVO),
        fsr=FsrSettings(fsr_sim.device_path, threshold_n=holding_threshold_n, debounce_s=fsr_debounce_s),
        # The simulated servos on a pty answer from a Python thread sharing the GIL with the world and the
        # event loop, not from firmware: give a status packet 50 ms (a real chain needs under 20 ms).
        # In-process the same timeout passes in simulated time when an answer is withheld (a silent servo).
        retries=3,
        read_timeout_s=0.05,
        open_bus=servo_sim.open_serial,
        open_fsr=fsr_sim.open_serial,
        inline_bus=transport == "inprocess" and clock.simulated,
        health=health or HealthLimits(),
    )
    devices = await open_device_stack(spec, stack, clock=clock, on_event=on_event)
    return CellDevices(servo_sim=servo_sim, fsr_sim=fsr_sim, stack=devices)


__all__ = ["GRIPPER_SERVO", "TRANSPORTS", "CellDevices", "arm_servos", "open_cell_devices"]
