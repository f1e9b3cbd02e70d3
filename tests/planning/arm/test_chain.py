"""The bundled URDF is Table 3.1 read in the modified (Craig) convention, and Pinocchio agrees with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from description import thesis
from description.arm import build_urdf, finger_length_from_payload_reach
from planning.arm import BUNDLED_URDF, ArmModel, ArmModelError, InvalidTarget


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _craig(a: float, d: float, alpha: float, theta: float) -> np.ndarray:
    ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
    rx = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1]], dtype=float)
    tx = np.eye(4)
    tx[0, 3] = a
    rz = np.array([[ct, -st, 0, 0], [st, ct, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    tz = np.eye(4)
    tz[2, 3] = d
    return np.asarray(rx @ tx @ rz @ tz)


def test_bundled_urdf_is_what_the_generator_writes() -> None:
    assert BUNDLED_URDF.read_text(encoding="utf-8") == build_urdf()


def test_joint_order_is_the_thesis_servo_order(arm: ArmModel) -> None:
    assert arm.joint_names == tuple(j for j, _ in thesis.JOINT_SERVOS[:5])
    assert [s.name for s in arm.servo_models] == [s for _, s in thesis.JOINT_SERVOS[:5]]


def test_shoulder_turn_axis_is_vertical_and_lift_axes_are_parallel_and_horizontal(arm: ArmModel) -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(arm.lower, arm.upper)
        arm.joint_positions(q)
        axes = [arm.data.oMi[i].rotation[:, 2] for i in range(1, 6)]
        assert np.allclose(np.abs(axes[0]), [0, 0, 1], atol=1e-9)
        for lift in axes[2:4]:
            assert abs(float(axes[1] @ lift)) == pytest.approx(1.0, abs=1e-9)
        assert abs(axes[1][2]) < 1e-7
        # The wrist turn axis lies in the arm's vertical plane, perpendicular to the lift axes.
        assert abs(float(axes[4] @ axes[1])) < 1e-7


def test_stretched_arm_reaches_about_0_58_m_from_shoulder_to_wrist(arm: ArmModel) -> None:
    joints = arm.joint_positions([0.0, 0.0, 0.0, 0.0, 0.0])
    shoulder_to_wrist = float(np.linalg.norm(joints[3] - joints[1]))
    assert shoulder_to_wrist == pytest.approx(0.294 + 0.2838, abs=1e-3)
    assert 0.57 < shoulder_to_wrist < 0.59


def test_stretched_side_grasp_holds_the_mug_at_the_rated_payload_reach(arm: ArmModel) -> None:
    position, rotation = arm.fk([0.0, 0.0, 0.0, -math.pi / 2, -math.pi / 2])
    assert position[0] == pytest.approx(thesis.ARM_PAYLOAD_REACH_M, abs=1e-3)
    assert np.allclose(rotation[:, 2], [1, 0, 0], atol=1e-6)  # approach forward
    assert np.allclose(rotation[:, 0], [0, 0, 1], atol=1e-6)  # wrist turn -pi/2: the upside-down grasp
    assert finger_length_from_payload_reach() == pytest.approx(0.0572, abs=1e-4)


def test_fk_matches_the_modified_dh_product_of_table_3_1(arm: ArmModel) -> None:
    rng = np.random.default_rng(7)
    desc_base = 0.05
    tool_offset = np.eye(4)
    tool_offset[2, 3] = finger_length_from_payload_reach()
    for _ in range(10):
        q = rng.uniform(arm.lower, arm.upper)
        t = np.eye(4)
        t[2, 3] = desc_base
        for row, theta in zip(thesis.DH_TABLE, [*q, 0.0], strict=True):
            t = t @ _craig(row.a_m, row.d_m, row.alpha_rad, theta)
        expected = (t @ tool_offset)[:3, 3]
        position, _ = arm.fk(q)
        assert np.allclose(position, expected, atol=1e-9)


def test_fk_refuses_a_short_joint_vector(arm: ArmModel) -> None:
    with pytest.raises(InvalidTarget, match=r"^expected 5 joint angles \(shoulder_turn, shoulder_lift, "):
        arm.fk([0.0, 0.0])


def test_fk_refuses_nan(arm: ArmModel) -> None:
    with pytest.raises(
        InvalidTarget, match=r"^joint angles must be finite, got \[nan, 0.0, 0.0, 0.0, 0.0\]$"
    ):
        arm.fk([math.nan, 0.0, 0.0, 0.0, 0.0])


def test_links_carry_their_servo_masses(arm: ArmModel) -> None:
    masses = {arm.model.names[i]: arm.model.inertias[i].mass for i in range(1, arm.model.njoints)}
    assert masses["elbow_lift"] > 0.126  # forearm plates plus the MX-28T at its end
    assert masses["shoulder_lift"] > 0.126 + 0.1
    total = sum(masses.values())
    assert 0.5 < total < 1.5


def test_loading_a_missing_urdf_names_the_file(tmp_path: object) -> None:
    from pathlib import Path

    missing = Path(str(tmp_path)) / "nope.urdf"
    with pytest.raises(
        ArmModelError, match=rf"^cannot read the arm URDF {missing}: No such file or directory$"
    ):
        ArmModel.load(missing)


def test_a_joint_without_a_known_servo_is_refused() -> None:
    with pytest.raises(
        ArmModelError, match=r"^joint 'shoulder_turn' of .*thesis_arm.urdf has servo None; map it to"
    ):
        ArmModel.load(servos={})


def test_every_urdf_joint_limit_is_a_position_its_servo_can_take(arm: ArmModel) -> None:
    """No limit the planner may use needs clamping by the driver: each lies within the servo's ticks."""
    from drivers.dynamixel.tables import MODELS

    servos = dict(thesis.JOINT_SERVOS)
    for i, name in enumerate(arm.joint_names):
        servo = MODELS[servos[name]]
        low, high = servo.rad_from_ticks(0), servo.rad_from_ticks(servo.max_tick)
        # The URDF keeps 9 significant digits, a few 1e-9 rad either way.
        assert low - 1e-8 <= float(arm.lower[i]), name
        assert float(arm.upper[i]) <= high + 1e-8, name
    wrist = arm.joint_names.index("wrist_turn")
    assert float(arm.upper[wrist]) == pytest.approx(math.radians(149.70703125))


def test_forward_kinematics_of_many_poses_is_that_of_each_pose(arm: ArmModel) -> None:
    qs = np.random.default_rng(7).uniform(arm.lower, arm.upper, (200, arm.dof))
    positions, rotations, origins = arm.fk_many(qs)
    for q, p, r, o in zip(qs, positions, rotations, origins, strict=True):
        one_p, one_r = arm.fk(q)
        np.testing.assert_allclose(p, one_p, atol=1e-12)
        np.testing.assert_allclose(r, one_r, atol=1e-12)
        np.testing.assert_allclose(o, arm.joint_positions(q), atol=1e-12)
