"""Dynamixel servos: control tables, packet codecs, the bus on dynamixel-sdk, the arm and the gripper.

Typical use::

    async with ServoChain(BusConfig("/dev/ttyUSB0"), chain_models) as chain:
        async with DynamixelArm(chain, thesis_joints()) as arm, DynamixelGripper(chain, spec, fsr) as grip:
            await arm.follow(trajectory)

The bus, chain, arm and gripper load dynamixel-sdk and numpy, so they are imported on first use: the control
tables and bus settings (what checking a config needs) come without them.
"""

import importlib
from typing import TYPE_CHECKING

from drivers.dynamixel.config import BusConfig, GripperSpec, JointSpec, thesis_joints
from drivers.dynamixel.tables import MODELS, ModelSpec

if TYPE_CHECKING:
    from drivers.dynamixel.arm import DynamixelArm
    from drivers.dynamixel.bus import (
        BusCorrupt,
        BusTimeout,
        ChainMismatch,
        DeviceEvent,
        DynamixelBus,
        ServoCounters,
        ServoReading,
    )
    from drivers.dynamixel.chain import ServoChain
    from drivers.dynamixel.gripper import DynamixelGripper

_ON_FIRST_USE = {
    "DynamixelArm": "drivers.dynamixel.arm",
    "BusCorrupt": "drivers.dynamixel.bus",
    "BusTimeout": "drivers.dynamixel.bus",
    "ChainMismatch": "drivers.dynamixel.bus",
    "DeviceEvent": "drivers.dynamixel.bus",
    "DynamixelBus": "drivers.dynamixel.bus",
    "ServoCounters": "drivers.dynamixel.bus",
    "ServoReading": "drivers.dynamixel.bus",
    "ServoChain": "drivers.dynamixel.chain",
    "DynamixelGripper": "drivers.dynamixel.gripper",
}

__all__ = [
    "MODELS",
    "BusConfig",
    "BusCorrupt",
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


def __getattr__(name: str) -> object:
    module = _ON_FIRST_USE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
