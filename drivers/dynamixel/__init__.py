"""Dynamixel servos: control tables, packet codecs, the bus on dynamixel-sdk, the arm and the gripper.

Typical use::

    async with ServoChain(BusConfig("/dev/ttyUSB0"), chain_models) as chain:
        async with DynamixelArm(chain, thesis_joints()) as arm, DynamixelGripper(chain, spec, fsr) as grip:
            await arm.follow(trajectory)
"""

from drivers.dynamixel.arm import DynamixelArm
from drivers.dynamixel.bus import (
    BusTimeout,
    ChainMismatch,
    DeviceEvent,
    DynamixelBus,
    ServoCounters,
    ServoReading,
)
from drivers.dynamixel.chain import ServoChain
from drivers.dynamixel.config import BusConfig, GripperSpec, JointSpec, thesis_joints
from drivers.dynamixel.gripper import DynamixelGripper
from drivers.dynamixel.tables import MODELS, ModelSpec

__all__ = [
    "MODELS",
    "BusConfig",
    "BusTimeout",
    "ChainMismatch",
    "DeviceEvent",
    "DynamixelArm",
    "DynamixelBus",
    "DynamixelGripper",
    "GripperSpec",
    "JointSpec",
    "ModelSpec",
    "ServoChain",
    "ServoCounters",
    "ServoReading",
    "thesis_joints",
]
