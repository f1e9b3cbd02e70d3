"""The cycle planner's plan played on the physics world: the mug ends on its slot, a centimetre from a
placed neighbour, without touching it, with its handle where the planner predicted."""

from __future__ import annotations

import math

import pytest

from daemon.config import load_config
from description.arm import JOINT_LIMITS
from description.cell import SceneMug
from description.thesis import BIG_MUG, MUG_TYPES, SMALL_MUG, MugSpec
from drivers.interfaces import JointTrajectory
from planning.arm.model import ArmModel
from planning.interfaces import MugPose, StepKind, TraySlot
from planning.motion import CyclePlanner
from sim.mujoco.collisions import TrayCollisionCounter
from sim.mujoco.world import SimWorld
from tests.sim.mujoco.conftest import ARM_IDS, GRIPPER_ID, Hand, WorldFactory, cell_layout, mug_facing_arm

GRIPPER_SPEED_RAD_S = 1.5  # the gripper driver's moving speed


def _follow(world: SimWorld, trajectory: JointTrajectory) -> None:
    """Stream the trajectory's samples as the arm driver does: each a goal with the speed that reaches it
    on time."""
    times, positions = trajectory.times, trajectory.positions
    for k in range(1, len(times)):
        dt = float(times[k] - times[k - 1])
        if dt <= 0.0:
            continue
        for j, servo_id in enumerate(ARM_IDS):
            delta = abs(float(positions[k, j] - positions[k - 1, j]))
            world.set_goal(servo_id, float(positions[k, j]), max(delta / dt, 1e-3))
        world.step_for(dt)
    world.step_for(0.2)


def _open(world: SimWorld, arm: ArmModel, aperture_m: float | None) -> None:
    """As the gripper driver opens: fully (the joint's lower limit) or to an aperture."""
    angle = JOINT_LIMITS["gripper"].lower_rad
    if aperture_m is not None:
        angle = max(arm.gripper.angle_for_aperture(aperture_m), angle)
    world.set_goal(GRIPPER_ID, angle, GRIPPER_SPEED_RAD_S)
    world.step_for(0.6)


@pytest.mark.parametrize("mug_spec", [SMALL_MUG, BIG_MUG], ids=["small", "big"])
@pytest.mark.slow
def test_a_planned_cycle_places_the_mug_on_its_slot_beside_a_neighbour_without_touching_it(
    make_world: WorldFactory, arm_model: ArmModel, mug_spec: MugSpec
) -> None:
    cell = load_config().cell
    slot = TraySlot("a", mug_spec.name, 0.52, 0.05)
    # A small mug already on the tray 1 cm (the packing tolerance) to the slot's right, handle along +x.
    gap = mug_spec.diameter_mm / 2000.0 + SMALL_MUG.diameter_mm / 2000.0 + 0.010
    neighbour = TraySlot("n", "small", slot.x_m, slot.y_m - gap, handle_yaw_rad=0.0)
    counter = mug_facing_arm("a", mug_spec, 0.10, 0.40)
    world = make_world(
        [counter, SceneMug("n", SMALL_MUG, neighbour.x_m, neighbour.y_m, yaw_rad=0.0, upside_down=True)]
    )
    collisions = TrayCollisionCounter(world, cell_layout().tray.region_m)
    planner = CyclePlanner(arm_model, cell, MUG_TYPES)
    start = [world.present(i)[0] for i in ARM_IDS]
    pose = MugPose("a", mug_spec.name, counter.x_m, counter.y_m, handle_yaw_rad=counter.yaw_rad)
    cycle = planner.plan_cycle(start, pose, slot, [neighbour])
    hand = Hand(world, arm_model)
    for step in cycle.steps:
        if step.kind is StepKind.MOVE:
            assert step.trajectory is not None
            _follow(world, step.trajectory)
        elif step.kind is StepKind.CLOSE:
            assert hand.close_until(2.0), step.phase
        else:
            _open(world, arm_model, step.aperture_m)
    world.step_for(0.5)
    truth = world.mug_truths()
    placed, other = truth["a"], truth["n"]
    assert placed.orientation == "inverted"
    assert math.dist(placed.position_m[:2], (slot.x_m, slot.y_m)) < 0.004
    w, x, y, z = placed.quat_wxyz
    handle_yaw = math.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))
    assert cycle.handle_yaw_rad is not None
    assert abs(math.remainder(handle_yaw - cycle.handle_yaw_rad, math.tau)) < math.radians(6)
    assert math.dist(other.position_m[:2], (neighbour.x_m, neighbour.y_m)) < 0.001
    assert collisions.collisions == []
