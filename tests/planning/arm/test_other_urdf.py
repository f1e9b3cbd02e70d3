"""Any other URDF arm can be configured: a 6-DOF arm loads, and FK/IK work with the generic seeds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planning.arm import ArmModel, ArmModelError, GraspTarget

SIX_DOF = """<?xml version="1.0"?>
<robot name="six">
  <link name="base"/>
  {links}
  <link name="tool"/>
  <joint name="tool_mount" type="fixed">
    <parent link="l6"/><child link="tool"/><origin xyz="0 0 0.08"/>
  </joint>
</robot>
"""
JOINTS = [
    ("j1", "0 0 0.1", "0 0 1"),
    ("j2", "0 0 0.05", "0 1 0"),
    ("j3", "0.25 0 0", "0 1 0"),
    ("j4", "0.2 0 0", "1 0 0"),
    ("j5", "0.05 0 0", "0 1 0"),
    ("j6", "0.05 0 0", "1 0 0"),
]
SERVOS = {f"j{i}": "MX-64T" for i in range(1, 7)}


def _urdf(tmp_path: Path) -> Path:
    parts = []
    parent = "base"
    for i, (name, xyz, axis) in enumerate(JOINTS, start=1):
        parts.append(
            f'<link name="l{i}"><inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4"'
            ' ixy="0" ixz="0" iyz="0"/></inertial></link>'
        )
        parts.append(
            f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="l{i}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
            '<limit lower="-2.5" upper="2.5" effort="5" velocity="3"/></joint>'
        )
        parent = f"l{i}"
    path = tmp_path / "six.urdf"
    path.write_text(SIX_DOF.format(links="\n  ".join(parts)), encoding="utf-8")
    return path


def test_a_six_dof_arm_solves_position_targets(tmp_path: Path) -> None:
    arm = ArmModel.load(_urdf(tmp_path), servos=SERVOS, tool_frame="tool", locked_joints=())
    assert arm.joint_names == tuple(SERVOS)
    rng = np.random.default_rng(5)
    solved = 0
    for _ in range(10):
        q = rng.uniform(arm.lower * 0.7, arm.upper * 0.7)
        position, _ = arm.fk(q)
        result = arm.ik(GraspTarget((float(position[0]), float(position[1]), float(position[2]))))
        if result.ok:
            solved += 1
            assert result.q is not None
            assert np.linalg.norm(arm.fk(result.q)[0] - position) <= 1e-3
    assert solved >= 9


def test_a_urdf_without_the_tool_frame_is_refused(tmp_path: Path) -> None:
    path = _urdf(tmp_path)
    with pytest.raises(
        ArmModelError, match=rf"^{path} has no frame 'grasp_point' to use as the grasp point$"
    ):
        ArmModel.load(path, servos=SERVOS, locked_joints=())


def test_locking_a_joint_the_urdf_lacks_is_refused(tmp_path: Path) -> None:
    path = _urdf(tmp_path)
    with pytest.raises(ArmModelError, match=rf"^{path} has no joint 'gripper' to lock \(locked_joints\)$"):
        ArmModel.load(path, servos=SERVOS, tool_frame="tool")


@pytest.mark.parametrize("last_joint", ["revolute", "prismatic"])
def test_forward_kinematics_of_many_poses_is_that_of_each_pose(tmp_path: Path, last_joint: str) -> None:
    """``fk_many`` (numpy over all poses for a chain of x, y and z joints; one Pinocchio call per pose
    otherwise, here a prismatic joint) gives what ``fk`` and ``joint_positions`` give pose by pose."""
    path = _urdf(tmp_path)
    path.write_text(
        path.read_text(encoding="utf-8").replace(
            'name="j6" type="revolute"', f'name="j6" type="{last_joint}"'
        ),
        encoding="utf-8",
    )
    arm = ArmModel.load(path, servos=SERVOS, tool_frame="tool", locked_joints=())
    qs = np.random.default_rng(3).uniform(arm.lower, arm.upper, (50, arm.dof))
    positions, rotations, origins = arm.fk_many(qs)
    for q, p, r, o in zip(qs, positions, rotations, origins, strict=True):
        one_p, one_r = arm.fk(q)
        np.testing.assert_allclose(p, one_p, atol=1e-12)
        np.testing.assert_allclose(r, one_r, atol=1e-12)
        np.testing.assert_allclose(o, arm.joint_positions(q), atol=1e-12)
