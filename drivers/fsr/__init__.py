"""The gripper's force-sensing resistor: the Arduino sketch's protocol and the asyncio reader."""

from drivers.fsr.reader import FsrCounters, FsrReader

__all__ = ["FsrCounters", "FsrReader"]
