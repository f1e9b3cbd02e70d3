"""The gripper's force-sensing resistor: the Arduino sketch's protocol, the reader's settings and the
asyncio reader.

The reader loads pyserial and the bus's types, so it is imported on first use: the settings (what checking a
config needs) come without them.
"""

import importlib
from typing import TYPE_CHECKING

from drivers.fsr.settings import FsrSettings

if TYPE_CHECKING:
    from drivers.fsr.reader import FsrCounters, FsrReader

_ON_FIRST_USE = {"FsrCounters": "drivers.fsr.reader", "FsrReader": "drivers.fsr.reader"}


def __getattr__(name: str) -> object:
    if name in _ON_FIRST_USE:
        return getattr(importlib.import_module(_ON_FIRST_USE[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FsrCounters", "FsrReader", "FsrSettings"]
