"""Dynamixel servo models as plain data: the datasheet figures the arm model, the planner and the energy
model need, one row per servo type.

The values are Robotis e-manual figures at 12 V (the supply voltage of the thesis arm). The planning limits
(``planning_speed_fraction``, ``max_accel_rad_s2``) are this project's choices: a loaded servo does not reach
its no-load speed, and the AX-12A has no acceleration profile of its own, so the planner keeps below both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

_RPM = 2.0 * math.pi / 60.0


@dataclass(frozen=True, slots=True)
class ServoModel:
    """One Dynamixel type: electrical, mechanical and motion figures (output shaft, 12 V)."""

    name: str
    protocol: float
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    standby_current_a: float
    mass_kg: float
    size_m: tuple[float, float, float]  # width, height (along the horn axis), depth
    gear_ratio: float
    position_range_rad: float  # full travel of joint mode
    resolution: int  # position steps over position_range_rad
    max_accel_rad_s2: float
    planning_speed_fraction: float = 0.5

    @property
    def travel_rad(self) -> tuple[float, float]:
        """The joint-mode travel about the centre position as the servo reaches it: ``resolution`` steps of
        ``position_range_rad / resolution`` from -resolution/2 to resolution/2 - 1 (AX-12A: -150° to
        149.7°), so a limit inside it never needs clamping to a position the servo can take."""
        step = self.position_range_rad / self.resolution
        half = self.resolution // 2
        return -half * step, (half - 1) * step

    @property
    def max_speed_rad_s(self) -> float:
        """The speed the planner allows: a fraction of the no-load speed, which loaded servos never reach."""
        return self.no_load_speed_rad_s * self.planning_speed_fraction

    def winding_resistance_ohm(self, supply_v: float) -> float:
        """Terminal resistance seen from the supply, from the stall current (R = V / I_stall)."""
        return supply_v / self.stall_current_a

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Output torque per ampere, gearbox included (k_t = stall torque / stall current)."""
        return self.stall_torque_nm / self.stall_current_a

    def back_emf_v_s_per_rad(self, supply_v: float) -> float:
        """Output-referred back-EMF constant from the no-load speed (k_e = V / omega_0)."""
        return supply_v / self.no_load_speed_rad_s


SERVO_MODELS: Final[dict[str, ServoModel]] = {
    "MX-106T": ServoModel(
        "MX-106T",
        protocol=1.0,
        stall_torque_nm=8.4,
        stall_current_a=5.2,
        no_load_speed_rad_s=45.0 * _RPM,
        standby_current_a=0.1,
        mass_kg=0.153,
        size_m=(0.0402, 0.0651, 0.046),
        gear_ratio=225.0,
        position_range_rad=2.0 * math.pi,
        resolution=4096,
        max_accel_rad_s2=3.0,
    ),
    "MX-64T": ServoModel(
        "MX-64T",
        protocol=1.0,
        stall_torque_nm=6.0,
        stall_current_a=4.1,
        no_load_speed_rad_s=63.0 * _RPM,
        standby_current_a=0.1,
        mass_kg=0.126,
        size_m=(0.0402, 0.0611, 0.041),
        gear_ratio=200.0,
        position_range_rad=2.0 * math.pi,
        resolution=4096,
        max_accel_rad_s2=4.0,
    ),
    "MX-28T": ServoModel(
        "MX-28T",
        protocol=1.0,
        stall_torque_nm=2.5,
        stall_current_a=1.4,
        no_load_speed_rad_s=55.0 * _RPM,
        standby_current_a=0.1,
        mass_kg=0.072,
        size_m=(0.0356, 0.0506, 0.0355),
        gear_ratio=193.0,
        position_range_rad=2.0 * math.pi,
        resolution=4096,
        max_accel_rad_s2=6.0,
    ),
    "AX-12A": ServoModel(
        "AX-12A",
        protocol=1.0,
        stall_torque_nm=1.5,
        stall_current_a=1.5,
        no_load_speed_rad_s=59.0 * _RPM,
        standby_current_a=0.05,
        mass_kg=0.0546,
        size_m=(0.032, 0.050, 0.040),
        gear_ratio=254.0,
        position_range_rad=math.radians(300.0),
        resolution=1024,
        max_accel_rad_s2=6.0,
    ),
}
