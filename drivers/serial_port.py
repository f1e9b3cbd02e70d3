"""The serial-port seam under the Dynamixel bus and the FSR reader: the part of pyserial's ``Serial`` used.

On the robot the ports are pyserial's, opened on the adapters' device files. The simulated cell may hand
the same drivers ports of ``drivers.sim.inprocess`` instead, which carry the same bytes to the device
simulators inside this process, without a pseudo-terminal's latency; the driver code above the port is the
same either way.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import serial


class SerialPort(Protocol):
    """An open serial port, non-blocking (pyserial's ``Serial(..., timeout=0)``): ``read`` returns what has
    arrived (maybe nothing), ``fileno`` can be waited on with ``select`` or ``loop.add_reader``."""

    baudrate: int

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def fileno(self) -> int: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


OpenSerial = Callable[[str, int], SerialPort]
"""Opens a port by name at a baud rate; raises ``serial.SerialException`` (or ``OSError``) when it cannot."""


def open_pyserial(port: str, baudrate: int) -> SerialPort:
    """The port on the device file ``port`` (a USB adapter, or a pseudo-terminal)."""
    ser: SerialPort = serial.Serial(port, baudrate, timeout=0)
    return ser


__all__ = ["OpenSerial", "SerialPort", "open_pyserial"]
