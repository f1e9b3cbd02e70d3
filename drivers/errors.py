"""Exceptions raised by device drivers. Messages name the port, servo id or register and say what to do."""

from __future__ import annotations


class DriverError(RuntimeError):
    """Base of every device failure; the daemon enters ``fault`` on one."""


class ServoFault(DriverError):
    """A servo reported an error bit (overload, overheating, ...) or stopped answering."""

    def __init__(self, message: str, *, servo_id: int | None = None, bits: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.bits = bits


class BusLost(ConnectionError):
    """The serial link to a device is gone (USB unplugged, port closed)."""

    def __init__(self, message: str, *, port: str = "") -> None:
        super().__init__(message)
        self.port = port


class LimitViolation(ValueError):
    """A command was refused because it leaves a joint's software limits; nothing was sent."""


class SensorFault(DriverError):
    """A sensor stream stopped or only sends garbage."""
