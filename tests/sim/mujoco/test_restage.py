"""Setting the physics world to a state seen elsewhere (a re-simulation from a recording): a mug put in the
gripper by ``SimWorld.hold`` is held as a real grasp holds it."""

from __future__ import annotations

import math

import numpy as np

from description.thesis import SMALL_MUG
from sim.mujoco.arm import ArmMjcf
from sim.mujoco.scene import build_mjcf
from sim.mujoco.world import HeldMug, SimWorld
from tests.sim.mujoco.conftest import GRIPPER_ID, OneMugFactory, cell_layout


def test_a_mug_put_in_the_gripper_stays_where_a_real_grasp_held_it(
    one_mug: OneMugFactory, arm_mjcf: ArmMjcf
) -> None:
    cell = one_mug(SMALL_MUG)
    world, mug = cell.world, cell.mug
    cell.lift(cell.grip(), z_m=0.22)
    world.step_for(1.0)
    grasped = world.mug_truths()["a"]
    assert grasped.held
    pose = {s.joint: world.present(s.servo_id)[0] for s in arm_mjcf.servos}
    w, x, y, z = grasped.quat_wxyz
    axis = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
    # A fresh world, the mug standing on the counter, the arm where it was: the mug put in the gripper.
    xml = build_mjcf(
        cell_layout(), [mug], arm_body_xml=arm_mjcf.body_xml, arm_actuator_xml=arm_mjcf.actuator_xml
    )
    again = SimWorld(xml, arm_mjcf, mug_ids=["a"], initial_pose_rad=pose)
    aperture = world.arm.gripper.aperture_m(world.present(GRIPPER_ID)[0])
    again.hold(HeldMug("a", grasped.position_m, axis, mug.yaw_rad, aperture, world.gripper_force_n()))
    again.step_for(1.0)
    held = again.mug_truths()["a"]
    assert held.held
    assert again.held_mug == "a"
    assert held.orientation == "upright"
    assert math.dist(held.position_m, grasped.position_m) < 0.01
    assert held.speed_m_s < 0.01
    assert again.gripper_force_n() > 1.0  # the force sensor feels the mug it holds
    # And it is a grasp like any other: opening the jaw lets the mug fall.
    again.set_goal(GRIPPER_ID, -0.35, 3.0)
    again.step_for(1.5)
    assert again.held_mug is None
    assert float(np.asarray(again.mug_truths()["a"].position_m)[2]) < 0.01
