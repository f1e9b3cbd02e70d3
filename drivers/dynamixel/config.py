"""Frozen, validated configuration of the servo bus, the arm joints, the gripper and the servos' health
limits (light: checking a config file imports this module, not the bus)."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated

from drivers.dynamixel.protocol import MAX_ID, Protocol
from drivers.dynamixel.tables import BAUD_CODES_1, BAUD_CODES_2, ModelSpec, model
from validation import Invalid, within


@dataclass(frozen=True, slots=True)
class BusConfig:
    """The serial adapter the chain hangs on: device path, baud rate and protocol version."""

    port: str
    baudrate: int = 1_000_000
    protocol: Protocol = 1

    def __post_init__(self) -> None:
        if not self.port:
            raise ValueError("bus.port is empty; name the serial device, e.g. /dev/ttyUSB0")
        if self.protocol not in (1, 2):
            raise ValueError(f"bus.protocol must be 1 or 2, got {self.protocol!r}")
        rates = BAUD_CODES_1 if self.protocol == 1 else BAUD_CODES_2
        if self.baudrate not in rates:
            allowed = ", ".join(str(r) for r in sorted(rates))
            raise ValueError(
                f"bus.baudrate {self.baudrate} is not a Protocol {self.protocol}.0 rate; use {allowed}"
            )


@dataclass(frozen=True, slots=True)
class JointSpec:
    """One arm joint: its name, the servo driving it and the software limits every command must respect."""

    name: str
    servo_id: int
    model: str
    min_rad: float
    max_rad: float

    def __post_init__(self) -> None:
        if not 0 <= self.servo_id <= MAX_ID:
            raise ValueError(f"joint {self.name}: servo_id {self.servo_id} is outside 0..{MAX_ID}")
        spec = model(self.model)
        if not self.min_rad < self.max_rad:
            raise ValueError(
                f"joint {self.name}: min_rad {self.min_rad} must be below max_rad {self.max_rad}"
            )
        lo, hi = spec.rad_from_ticks(0), spec.rad_from_ticks(spec.max_tick)
        if self.min_rad < lo or self.max_rad > hi:
            raise ValueError(
                f"joint {self.name}: limits [{self.min_rad:.3f}, {self.max_rad:.3f}] rad leave "
                f"the {self.model}'s range [{lo:.3f}, {hi:.3f}] rad"
            )

    @property
    def spec(self) -> ModelSpec:
        return model(self.model)


@dataclass(frozen=True, slots=True)
class GripperSpec:
    """The gripper servo and how its angle maps to the opening between the pads.

    ``aperture_map`` lists (servo angle rad, aperture m) pairs measured on the gripper, in increasing angle;
    the aperture must change monotonically with the angle. Closing moves in ``step_m`` steps every
    ``step_period_s``; ``grip_limit`` is the fraction of full torque allowed while closing, lowered by
    ``grip_limit_backoff`` after each overload, up to ``overload_retries`` recoveries.
    """

    servo_id: int = 6
    model: str = "AX-12A"
    aperture_map: tuple[tuple[float, float], ...] = ((-0.9, 0.12), (0.0, 0.07), (0.6, 0.0))
    open_aperture_m: float = 0.11
    step_m: float = 0.002
    step_period_s: float = 0.02
    grip_limit: float = 0.6
    grip_limit_backoff: float = 0.75
    overload_retries: int = 3
    speed_rad_s: float = 1.5

    def __post_init__(self) -> None:
        spec = model(self.model)
        if not 0 <= self.servo_id <= MAX_ID:
            raise ValueError(f"gripper.servo_id {self.servo_id} is outside 0..{MAX_ID}")
        angles = [a for a, _ in self.aperture_map]
        apertures = [m for _, m in self.aperture_map]
        if len(self.aperture_map) < 2 or angles != sorted(set(angles)):
            raise ValueError("gripper.aperture_map needs at least two points in strictly increasing angle")
        steps = [b - a for a, b in itertools.pairwise(apertures)]
        if not (all(s < 0 for s in steps) or all(s > 0 for s in steps)):
            raise ValueError("gripper.aperture_map must be strictly monotonic in aperture")
        if angles[0] < spec.rad_from_ticks(0) or angles[-1] > spec.rad_from_ticks(spec.max_tick):
            raise ValueError(f"gripper.aperture_map angles leave the {self.model}'s range")
        if not min(apertures) <= self.open_aperture_m <= max(apertures):
            raise ValueError(
                f"gripper.open_aperture_m {self.open_aperture_m} is outside the mapped "
                f"{min(apertures)}..{max(apertures)} m"
            )
        if not 0 < self.grip_limit <= 1 or not 0 < self.grip_limit_backoff < 1:
            raise ValueError("gripper.grip_limit must be in (0, 1] and grip_limit_backoff in (0, 1)")
        if self.overload_retries < 0 or self.step_m <= 0 or self.step_period_s <= 0:
            raise ValueError("gripper.overload_retries must be >= 0, step_m and step_period_s > 0")

    @property
    def spec(self) -> ModelSpec:
        return model(self.model)

    def angle_for(self, aperture_m: float) -> float:
        """Servo angle for an opening, clamped to the mapped range."""
        points = sorted(self.aperture_map, key=lambda pair: pair[1])
        return _interp(aperture_m, [m for _, m in points], [a for a, _ in points])

    def aperture_for(self, angle_rad: float) -> float:
        return _interp(angle_rad, [a for a, _ in self.aperture_map], [m for _, m in self.aperture_map])


def _interp(x: float, xs: Sequence[float], ys: Sequence[float]) -> float:
    if x <= xs[0]:
        return ys[0]
    for (x0, y0), (x1, y1) in zip(zip(xs, ys, strict=True), zip(xs[1:], ys[1:], strict=True), strict=False):
        if x <= x1:
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return ys[-1]


def thesis_joints(
    limits_rad: Sequence[tuple[float, float]] | None = None, *, first_id: int = 1
) -> tuple[JointSpec, ...]:
    """The thesis arm's five joints (gripper excluded) with ids from ``first_id`` (§3.2.1)."""
    from description.thesis import JOINT_SERVOS

    arm = [(name, servo) for name, servo in JOINT_SERVOS if name != "gripper"]
    limits = limits_rad or [(-2.6, 2.6)] * len(arm)
    return tuple(
        JointSpec(name, first_id + i, servo, lo, hi)
        for i, ((name, servo), (lo, hi)) in enumerate(zip(arm, limits, strict=True))
    )


@dataclass(frozen=True, slots=True)
class HealthLimits:
    """How the servos' health is judged (``[hardware.health]`` in the config is this type): every
    ``poll_period_s`` their supply voltage (a warning ``voltage_warn_margin_v`` inside
    ``voltage_min_v``..``voltage_max_v``, a fault outside) and temperature (a warning from
    ``temperature_warn_c``, a fault past ``temperature_limit_c``); and when the bus calls a servo's answers
    too corrupt (more than ``corrupt_rate_max`` of its last ``corrupt_window``)."""

    poll_period_s: Annotated[float, within(0.05, 60.0)] = 1.0
    voltage_min_v: Annotated[float, within(0.0, 30.0)] = 10.0
    voltage_max_v: Annotated[float, within(0.0, 30.0)] = 14.0
    voltage_warn_margin_v: Annotated[float, within(0.0, 5.0)] = 0.5
    temperature_warn_c: Annotated[float, within(0.0, 100.0)] = 60.0
    temperature_limit_c: Annotated[float, within(0.0, 100.0)] = 70.0
    corrupt_rate_max: Annotated[float, within(0.0, 1.0)] = 0.2
    corrupt_window: Annotated[int, within(1, 10_000)] = 50

    def __post_init__(self) -> None:
        if not self.voltage_min_v + 2 * self.voltage_warn_margin_v < self.voltage_max_v:
            raise Invalid(
                f"voltage_max_v: {self.voltage_max_v:g} must be above voltage_min_v {self.voltage_min_v:g} "
                f"by more than twice voltage_warn_margin_v {self.voltage_warn_margin_v:g}"
            )
        if not self.temperature_warn_c < self.temperature_limit_c:
            raise Invalid(
                f"temperature_warn_c: {self.temperature_warn_c:g} must be below temperature_limit_c "
                f"{self.temperature_limit_c:g}"
            )
