"""What a servo's error byte means, decoded into names the logs, events and exceptions carry."""

from __future__ import annotations

from typing import Final

from drivers.dynamixel.protocol import Protocol

# Protocol 1.0 status error byte, bit by bit.
ERROR_BITS_1: Final = (
    "input_voltage",
    "angle_limit",
    "overheating",
    "range",
    "checksum",
    "overload",
    "instruction",
)
# Protocol 2.0: the status packet's error byte holds a number in bits 0-6 and the alert flag in bit 7,
# which says "read Hardware Error Status (70)" whose bits are listed below.
ERROR_NUMBERS_2: Final = {
    1: "result_fail",
    2: "instruction",
    3: "crc",
    4: "data_range",
    5: "data_length",
    6: "data_limit",
    7: "access",
}
ALERT_2: Final = 0x80
HARDWARE_ERROR_BITS_2: Final = {
    0: "input_voltage",
    2: "overheating",
    3: "motor_encoder",
    4: "electrical_shock",
    5: "overload",
}
# Errors after which the servo cuts its torque and needs a recovery step.
SHUTDOWN_FAULTS: Final = frozenset({"overload", "overheating", "electrical_shock", "motor_encoder"})


def error_names(protocol: Protocol, error: int) -> tuple[str, ...]:
    """Names of the conditions in a status packet's error byte (2.0: ``alert`` means 'read address 70')."""
    if protocol == 1:
        return tuple(name for bit, name in enumerate(ERROR_BITS_1) if error & (1 << bit))
    names: list[str] = []
    number = error & 0x7F
    if number:
        names.append(ERROR_NUMBERS_2.get(number, f"error_{number}"))
    if error & ALERT_2:
        names.append("alert")
    return tuple(names)


def hardware_error_names(status: int) -> tuple[str, ...]:
    """Names of the bits set in a 2.0 servo's Hardware Error Status register."""
    return tuple(name for bit, name in HARDWARE_ERROR_BITS_2.items() if status & (1 << bit))


def bits_for(protocol: Protocol, names: tuple[str, ...]) -> int:
    """The 1.0 error byte or 2.0 hardware-error-status value that carries ``names`` (for the simulator)."""
    if protocol == 1:
        return sum(1 << bit for bit, name in enumerate(ERROR_BITS_1) if name in names)
    return sum(1 << bit for bit, name in HARDWARE_ERROR_BITS_2.items() if name in names)
