"""Energy models: RNEA with the mug as payload through the servo motor model, the thesis's proxy, and the
placement planner's dynamics move cost."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.config import load_config
from description import thesis
from description.cell import CellLayout
from planning.arm import ArmModel, GraspKind
from planning.interfaces import MugPose, TraySlot
from planning.motion import (
    CyclePlanner,
    DynamicsEnergyModel,
    DynamicsMoveCost,
    JointPath,
    thesis_energy_j,
)
from planning.placement.cost import MoveCost

STRETCHED = np.array([0.0, 0.0, 0.0, -math.pi / 2, -math.pi / 2])  # arm level, gripper forward


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


@pytest.fixture(scope="module")
def cell() -> CellLayout:
    return load_config().cell


def test_held_mug_adds_its_weight_times_lever_to_the_shoulder_torque(arm: ArmModel) -> None:
    model = DynamicsEnergyModel(arm)
    zero = np.zeros((1, 5))
    empty = model.torques(STRETCHED[None, :], zero, zero)[0]
    loaded = model.torques(STRETCHED[None, :], zero, zero, payload_kg=0.2)[0]
    grasp, _ = arm.fk(STRETCHED)
    shoulder = arm.joint_positions(STRETCHED)[1]
    lever = float(grasp[0] - shoulder[0])
    assert abs(loaded[1] - empty[1]) == pytest.approx(0.2 * 9.81 * lever, rel=1e-3)
    # The shoulder turn axis is vertical: gravity puts no torque on it.
    assert abs(loaded[0]) < 1e-9


def test_holding_still_costs_only_copper_loss(arm: ArmModel) -> None:
    model = DynamicsEnergyModel(arm)
    zero = np.zeros((1, 5))
    tau = model.torques(STRETCHED[None, :], zero, zero)
    supply, copper = model.power_w(tau, zero)
    assert supply[0] == pytest.approx(copper[0])
    current = tau[0] / model.k_t
    assert copper[0] == pytest.approx(float(np.sum(model.resistance * current**2)))
    assert model.hold_energy_j(STRETCHED, 2.0) == pytest.approx(2.0 * copper[0])


def test_braking_draws_no_negative_power(arm: ArmModel) -> None:
    model = DynamicsEnergyModel(arm)
    tau = np.array([[0.0, 2.0, 0.0, 0.0, 0.0]])
    qd = np.array([[0.0, -3.0, 0.0, 0.0, 0.0]])  # the load drives the motor backwards
    supply, copper = model.power_w(tau, qd)
    assert supply[0] >= 0.0
    assert copper[0] > 0.0


def test_a_move_costs_more_with_a_mug_in_the_gripper(arm: ArmModel) -> None:
    model = DynamicsEnergyModel(arm)
    path = JointPath(
        np.array([STRETCHED, [1.0, -0.8, 1.2, -1.9, -1.5]]), arm.max_velocity, arm.max_acceleration
    )
    empty = model.path_energy(path, 50.0)
    loaded = model.path_energy(path, 50.0, payload_kg=0.2)
    assert loaded.total_j > empty.total_j > 0.0
    assert empty.copper_j <= empty.total_j + 1e-9


def test_thesis_proxy_is_weight_times_straight_distance() -> None:
    assert thesis_energy_j(0.2, (0.0, 0.4), (0.3, 0.0)) == pytest.approx(0.2 * thesis.GRAVITY_M_S2 * 0.5)


@pytest.mark.slow
def test_move_cost_tracks_the_planned_cycle(arm: ArmModel, cell: CellLayout) -> None:
    cost: MoveCost = DynamicsMoveCost(arm, cell)
    planner = CyclePlanner(arm, cell, thesis.MUG_TYPES)
    start = DynamicsMoveCost(arm, cell)._pose((0.5, 0.0), thesis.BIG_MUG, GraspKind.SIDE_UPSIDE_DOWN)
    assert start is not None
    for mug_xy, slot_xy in [((0.064, 0.415), (0.45, 0.05)), ((-0.25, 0.53), (0.58, -0.1))]:
        seconds, joules = cost(0.2, mug_xy, slot_xy)
        cycle = planner.plan_cycle(
            tuple(start), MugPose("a", "big", *mug_xy), TraySlot("a", "big", *slot_xy), []
        )
        assert seconds == pytest.approx(cycle.duration_s, rel=0.1)
        assert joules == pytest.approx(cycle.energy_j, rel=0.15)


def test_move_cost_of_an_unreachable_mug_is_the_thesis_time_limit(arm: ArmModel, cell: CellLayout) -> None:
    seconds, joules = DynamicsMoveCost(arm, cell)(0.2, (0.0, 0.95), (0.45, 0.0))
    assert seconds == thesis.MAX_SECONDS_PER_MUG
    assert math.isfinite(joules)
    assert joules > 1000.0
