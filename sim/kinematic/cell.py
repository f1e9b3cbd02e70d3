"""Build the kinematic cell: world, clock and devices in one bundle."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from drivers.interfaces import Clock, FloatArray
from planning.arm import ArmModel
from sim.kinematic.devices import SimArm, SimForceSensor, SimGripper
from sim.kinematic.world import KinematicWorld, MugGeometry, SimMug


@dataclass(frozen=True, slots=True)
class KinematicCell:
    """The simulated devices and the world behind them (tests and the daemon's sim backend use ``world``)."""

    world: KinematicWorld
    arm: SimArm
    gripper: SimGripper
    force: SimForceSensor


def open_kinematic_cell(
    mugs: Sequence[SimMug],
    mug_geometry: Mapping[str, MugGeometry],
    *,
    tray_origin_m: tuple[float, float],
    tray_size_m: tuple[float, float],
    clock: Clock,
    joint_speed_rad_s: float = 1.0,
    holding_threshold_n: float = 1.0,
    arm: ArmModel | None = None,
    q0: FloatArray | None = None,
) -> KinematicCell:
    """A kinematic cell with ``mugs`` on the counter, its devices moving on ``clock``."""
    world = KinematicWorld(
        arm or ArmModel.load(),
        list(mugs),
        dict(mug_geometry),
        tray_origin_m=tray_origin_m,
        tray_size_m=tray_size_m,
        clock=clock,
        q0=q0,
    )
    return KinematicCell(
        world=world,
        arm=SimArm(world, joint_speed_rad_s=joint_speed_rad_s),
        gripper=SimGripper(world),
        force=SimForceSensor(world, holding_threshold_n=holding_threshold_n),
    )
