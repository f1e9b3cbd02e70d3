"""Control tables of the supported Dynamixel models, as data, and the unit conversions they imply.

Addresses and units come from the ROBOTIS e-Manual pages of each model. Every register the driver touches is
named here once; the bus and the simulator look them up by name, so adding a model is adding one entry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

from drivers.dynamixel.protocol import Protocol


@dataclass(frozen=True, slots=True)
class Register:
    """One control-table entry: where it lives and how many bytes it spans."""

    address: int
    size: int
    signed: bool = False
    eeprom: bool = False


@dataclass(frozen=True, slots=True)
class ModelSpec:
    """What the driver needs to know about one servo model."""

    name: str
    number: int  # the model number register's value
    protocol: Protocol
    ticks_per_rev: float  # position resolution extended to a full turn (AX: 1024 ticks span 300°)
    center_tick: int  # the tick that maps to 0 rad
    max_tick: int
    speed_unit_rpm: float  # one tick of goal/present speed (1.0) or velocity (2.0)
    load_full_scale: int  # present load/current ticks that mean 100 % of the servo's torque
    default_torque_limit: int  # 1.0: Max Torque / Torque Limit; 2.0: Goal PWM at full
    registers: dict[str, Register]
    # The register the hot path reads per servo, and the goal block written by sync write.
    state_block: tuple[int, int]
    goal_block: tuple[int, int]
    control_table_size: int
    # ``rad_per_tick``, worked out once: every position a bus or its simulator converts divides by it.
    _rad_per_tick: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_rad_per_tick", 2 * math.pi / self.ticks_per_rev)

    def reg(self, name: str) -> Register:
        try:
            return self.registers[name]
        except KeyError:
            raise KeyError(f"{self.name} has no register {name!r}") from None

    @property
    def rad_per_tick(self) -> float:
        return self._rad_per_tick

    def ticks_from_rad(self, rad: float) -> int:
        """The goal position tick for a joint angle, clamped to the servo's range."""
        tick: int = round(self.center_tick + rad / self._rad_per_tick)
        return 0 if tick < 0 else self.max_tick if tick > self.max_tick else tick

    def rad_from_ticks(self, tick: int) -> float:
        return (tick - self.center_tick) * self._rad_per_tick

    def speed_ticks_from_rad_s(self, rad_s: float) -> int:
        """Goal speed (1.0) / profile velocity (2.0) ticks; never 0, which both protocols read as no limit."""
        tick = round(abs(rad_s) * 60 / (2 * math.pi) / self.speed_unit_rpm)
        return min(max(tick, 1), 1023 if self.protocol == 1 else 32767)

    def velocity_from_ticks(self, raw: int) -> float:
        """Present speed in rad/s (1.0 encodes the direction in bit 10; 2.0 is signed)."""
        if self.protocol == 1:
            magnitude = raw & 0x3FF
            signed = -magnitude if raw & 0x400 else magnitude
        else:
            signed = raw
        return signed * self.speed_unit_rpm * 2 * math.pi / 60

    def velocity_to_ticks(self, rad_s: float) -> int:
        """Inverse of :meth:`velocity_from_ticks` (used by the simulator)."""
        cap = 1023 if self.protocol == 1 else 32767
        magnitude = min(round(abs(rad_s) * 60 / (2 * math.pi) / self.speed_unit_rpm), cap)
        if self.protocol == 1:
            return magnitude | (0x400 if rad_s < 0 and magnitude else 0)
        return -magnitude if rad_s < 0 else magnitude

    def load_from_ticks(self, raw: int) -> float:
        """Present load as a signed fraction of full torque (1.0: bit 10 is the direction, CW negative)."""
        if self.protocol == 1:
            magnitude = raw & 0x3FF
            signed = -magnitude if raw & 0x400 else magnitude
        else:
            signed = raw
        return max(-1.0, min(1.0, signed / self.load_full_scale))

    def load_to_ticks(self, load: float) -> int:
        magnitude = min(round(abs(load) * self.load_full_scale), 1023 if self.protocol == 1 else 32767)
        if self.protocol == 1:
            return magnitude | (0x400 if load < 0 and magnitude else 0)
        return -magnitude if load < 0 else magnitude


def volts_from_ticks(raw: int) -> float:
    """Present voltage: 0.1 V per tick on both protocols."""
    return raw / 10.0


def _mx_1_registers(with_current: bool) -> dict[str, Register]:
    regs = {
        "model_number": Register(0, 2, eeprom=True),
        "firmware": Register(2, 1, eeprom=True),
        "id": Register(3, 1, eeprom=True),
        "baud_rate": Register(4, 1, eeprom=True),
        "return_delay": Register(5, 1, eeprom=True),
        "cw_angle_limit": Register(6, 2, eeprom=True),
        "ccw_angle_limit": Register(8, 2, eeprom=True),
        "temperature_limit": Register(11, 1, eeprom=True),
        "min_voltage": Register(12, 1, eeprom=True),
        "max_voltage": Register(13, 1, eeprom=True),
        "max_torque": Register(14, 2, eeprom=True),
        "status_return_level": Register(16, 1, eeprom=True),
        "alarm_led": Register(17, 1, eeprom=True),
        "shutdown": Register(18, 1, eeprom=True),
        "torque_enable": Register(24, 1),
        "led": Register(25, 1),
        "goal_position": Register(30, 2),
        "moving_speed": Register(32, 2),
        "torque_limit": Register(34, 2),
        "present_position": Register(36, 2),
        "present_speed": Register(38, 2),
        "present_load": Register(40, 2),
        "present_voltage": Register(42, 1),
        "present_temperature": Register(43, 1),
        "registered": Register(44, 1),
        "moving": Register(46, 1),
        "lock": Register(47, 1),
        "punch": Register(48, 2),
    }
    if with_current:
        regs["current"] = Register(68, 2)
    return regs


def _x_registers(load_name: str) -> dict[str, Register]:
    return {
        "model_number": Register(0, 2, eeprom=True),
        "firmware": Register(6, 1, eeprom=True),
        "id": Register(7, 1, eeprom=True),
        "baud_rate": Register(8, 1, eeprom=True),
        "return_delay": Register(9, 1, eeprom=True),
        "operating_mode": Register(11, 1, eeprom=True),
        "temperature_limit": Register(31, 1, eeprom=True),
        "max_voltage": Register(32, 2, eeprom=True),
        "min_voltage": Register(34, 2, eeprom=True),
        "pwm_limit": Register(36, 2, eeprom=True),
        "max_position": Register(48, 4, eeprom=True),
        "min_position": Register(52, 4, eeprom=True),
        "shutdown": Register(63, 1, eeprom=True),
        "torque_enable": Register(64, 1),
        "led": Register(65, 1),
        "status_return_level": Register(68, 1),
        "hardware_error_status": Register(70, 1),
        "goal_pwm": Register(100, 2, signed=True),
        "profile_acceleration": Register(108, 4),
        "profile_velocity": Register(112, 4),
        "goal_position": Register(116, 4, signed=True),
        "moving": Register(122, 1),
        "present_pwm": Register(124, 2, signed=True),
        load_name: Register(126, 2, signed=True),
        "present_velocity": Register(128, 4, signed=True),
        "present_position": Register(132, 4, signed=True),
        "present_voltage": Register(144, 2),
        "present_temperature": Register(146, 1),
    }


# Protocol 1.0 hot path: 36..43 = position, speed, load, voltage, temperature. Goal: position + speed.
_STATE_1: Final = (36, 8)
_GOAL_1: Final = (30, 4)
# Protocol 2.0 hot path: 126..146 = load/current, velocity, position, ..., voltage, temperature.
# Goal: profile velocity (112) + goal position (116).
_STATE_2: Final = (126, 21)
_GOAL_2: Final = (112, 8)


def _ax(name: str, number: int) -> ModelSpec:
    return ModelSpec(
        name=name,
        number=number,
        protocol=1,
        ticks_per_rev=1024 * 360 / 300,
        center_tick=512,
        max_tick=1023,
        speed_unit_rpm=0.111,
        load_full_scale=1023,
        default_torque_limit=1023,
        registers=_mx_1_registers(with_current=False),
        state_block=_STATE_1,
        goal_block=_GOAL_1,
        control_table_size=50,
    )


def _mx(name: str, number: int, with_current: bool) -> ModelSpec:
    return ModelSpec(
        name=name,
        number=number,
        protocol=1,
        ticks_per_rev=4096,
        center_tick=2048,
        max_tick=4095,
        speed_unit_rpm=0.114,
        load_full_scale=1023,
        default_torque_limit=1023,
        registers=_mx_1_registers(with_current),
        state_block=_STATE_1,
        goal_block=_GOAL_1,
        control_table_size=74,
    )


def _x(name: str, number: int, load_name: str, load_full_scale: int, pwm_limit: int) -> ModelSpec:
    return ModelSpec(
        name=name,
        number=number,
        protocol=2,
        ticks_per_rev=4096,
        center_tick=2048,
        max_tick=4095,
        speed_unit_rpm=0.229,
        load_full_scale=load_full_scale,
        default_torque_limit=pwm_limit,
        registers=_x_registers(load_name),
        state_block=_STATE_2,
        goal_block=_GOAL_2,
        control_table_size=147,
    )


MODELS: Final[dict[str, ModelSpec]] = {
    m.name: m
    for m in (
        _ax("AX-12A", 12),
        _mx("MX-28T", 29, with_current=False),
        _mx("MX-64T", 310, with_current=True),
        _mx("MX-106T", 320, with_current=True),
        # XL430: Present Load in 0.1 %; XM430: Present Current in 2.69 mA, full torque at the 1193 current
        # limit; XL330-M288: Present Current in mA, 1750 mA limit.
        _x("XL430-W250", 1060, "present_load", 1000, 885),
        _x("XM430-W350", 1020, "present_current", 1193, 885),
        _x("XL330-M288", 1200, "present_current", 1750, 885),
    )
}
MODELS_BY_NUMBER: Final[dict[int, ModelSpec]] = {m.number: m for m in MODELS.values()}

# Baud rate register values, limited to the rates dynamixel-sdk's PortHandler can set on the host side.
BAUD_CODES_1: Final[dict[int, int]] = {
    1_000_000: 1,
    500_000: 3,
    115_200: 16,
    57_600: 34,
    19_200: 103,
    9_600: 207,
}
BAUD_CODES_2: Final[dict[int, int]] = {
    9_600: 0,
    57_600: 1,
    115_200: 2,
    1_000_000: 3,
    2_000_000: 4,
    3_000_000: 5,
    4_000_000: 6,
}


def model(name: str) -> ModelSpec:
    """The spec of a model by its name, with a message listing the supported ones when it is unknown."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown Dynamixel model {name!r}; supported: {', '.join(MODELS)}") from None


def baud_code(protocol: Protocol, baudrate: int) -> int:
    codes = BAUD_CODES_1 if protocol == 1 else BAUD_CODES_2
    try:
        return codes[baudrate]
    except KeyError:
        allowed = ", ".join(str(b) for b in sorted(codes))
        raise ValueError(
            f"baud rate {baudrate} is not settable on Protocol {protocol}.0; use one of {allowed}"
        ) from None


def baud_from_code(protocol: Protocol, code: int) -> int | None:
    codes = BAUD_CODES_1 if protocol == 1 else BAUD_CODES_2
    return next((b for b, c in codes.items() if c == code), None)
