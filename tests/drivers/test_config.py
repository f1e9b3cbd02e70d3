"""Driver configuration is validated once, with messages naming the field and the allowed values."""

from __future__ import annotations

import math
import re

import pytest

from drivers.dynamixel import MODELS, BusConfig, GripperSpec, JointSpec
from drivers.dynamixel.tables import model


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: BusConfig(""), "bus.port is empty; name the serial device, e.g. /dev/ttyUSB0"),
        (lambda: BusConfig("/dev/x", protocol=3), "bus.protocol must be 1 or 2, got 3"),  # type: ignore[arg-type]
        (
            lambda: BusConfig("/dev/x", 4_000_000, 1),
            "bus.baudrate 4000000 is not a Protocol 1.0 rate; use 9600, 19200, 57600, 115200, 500000, "
            "1000000",
        ),
        (
            lambda: JointSpec("elbow_lift", 300, "MX-64T", -1, 1),
            "joint elbow_lift: servo_id 300 is outside 0..252",
        ),
        (
            lambda: JointSpec("elbow_lift", 3, "MX-65T", -1, 1),
            "unknown Dynamixel model 'MX-65T'; supported: AX-12A, MX-28T, MX-64T, MX-106T, XL430-W250, "
            "XM430-W350, XL330-M288",
        ),
        (
            lambda: JointSpec("elbow_lift", 3, "MX-64T", 1, -1),
            "joint elbow_lift: min_rad 1 must be below max_rad -1",
        ),
        (
            lambda: JointSpec("wrist_turn", 5, "AX-12A", -3.0, 1.0),
            "joint wrist_turn: limits [-3.000, 1.000] rad leave the AX-12A's range [-2.618, 2.613] rad",
        ),
        (
            lambda: GripperSpec(aperture_map=((0.0, 0.1), (0.0, 0.05))),
            "gripper.aperture_map needs at least two points in strictly increasing angle",
        ),
        (
            lambda: GripperSpec(aperture_map=((0.0, 0.1), (0.2, 0.05), (0.4, 0.07))),
            "gripper.aperture_map must be strictly monotonic in aperture",
        ),
        (
            lambda: GripperSpec(open_aperture_m=0.5),
            "gripper.open_aperture_m 0.5 is outside the mapped 0.0..0.12 m",
        ),
        (
            lambda: GripperSpec(grip_limit=1.5),
            "gripper.grip_limit must be in (0, 1] and grip_limit_backoff in (0, 1)",
        ),
    ],
)
def test_bad_driver_config_is_refused_with_the_field_named(make: object, message: str) -> None:
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        make()  # type: ignore[operator]


def test_gripper_aperture_and_angle_maps_are_inverse() -> None:
    spec = GripperSpec()
    for aperture in (0.0, 0.03, 0.074, 0.091, 0.11):
        assert spec.aperture_for(spec.angle_for(aperture)) == pytest.approx(aperture)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_ticks_and_radians_round_trip_within_one_tick(name: str) -> None:
    spec = model(name)
    for rad in (-1.0, -0.01, 0.0, 0.5, 2.0):
        assert abs(spec.rad_from_ticks(spec.ticks_from_rad(rad)) - rad) <= spec.rad_per_tick / 2 + 1e-12
    assert spec.rad_from_ticks(spec.center_tick) == 0.0
    assert spec.ticks_from_rad(10.0) == spec.max_tick


@pytest.mark.parametrize("name", sorted(MODELS))
def test_speed_and_load_conversions_keep_their_sign(name: str) -> None:
    spec = model(name)
    assert spec.velocity_from_ticks(spec.velocity_to_ticks(-1.0)) == pytest.approx(-1.0, abs=0.03)
    assert spec.load_from_ticks(spec.load_to_ticks(-0.5)) == pytest.approx(-0.5, abs=0.002)
    assert spec.speed_ticks_from_rad_s(0.0) == 1  # never 0, which means "no limit" on the wire


def test_mx_speed_unit_is_0_114_rpm() -> None:
    assert model("MX-64T").velocity_from_ticks(100) == pytest.approx(100 * 0.114 * 2 * math.pi / 60)
    assert model("MX-64T").velocity_from_ticks(0x400 | 100) == pytest.approx(-100 * 0.114 * 2 * math.pi / 60)
