"""Inverse kinematics: sub-millimetre solutions inside the limits, and a clear reason when there is none."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.arm import ArmModel, GraspKind, GraspTarget


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _reachable_samples(arm: ArmModel, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(arm.lower * 0.8, arm.upper * 0.8) for _ in range(n)]


def test_position_ik_recovers_fk_of_random_poses_within_a_millimetre(arm: ArmModel) -> None:
    for q in _reachable_samples(arm, 40, 3):
        position, _ = arm.fk(q)
        result = arm.ik(GraspTarget(tuple(position)))
        assert result.ok, result.reason
        assert result.q is not None
        reached, _ = arm.fk(result.q)
        assert float(np.linalg.norm(reached - position)) <= 1e-3
        assert result.residual_m <= 1e-3
        assert arm.limit_violations(result.q) == []


@pytest.mark.parametrize("kind", [GraspKind.SIDE, GraspKind.SIDE_UPSIDE_DOWN])
def test_side_grasp_ik_is_horizontal_radial_and_rolled_as_asked(arm: ArmModel, kind: GraspKind) -> None:
    for x, y, z in [
        (0.45, 0.0, 0.06),
        (0.3, 0.45, 0.06),
        (-0.2, 0.5, 0.196),
        (0.5, -0.3, 0.196),
        (0.6, 0.2, 0.06),
    ]:
        result = arm.ik(GraspTarget((x, y, z), kind))
        assert result.ok, result.reason
        assert result.q is not None
        position, rotation = arm.fk(result.q)
        assert np.allclose(position, [x, y, z], atol=1e-3)
        approach = rotation[:, 2]
        assert abs(approach[2]) < 2e-3
        assert math.atan2(approach[1], approach[0]) == pytest.approx(math.atan2(y, x), abs=2e-3)
        x_axis_z = -1.0 if kind is GraspKind.SIDE else 1.0
        assert rotation[2, 0] == pytest.approx(x_axis_z, abs=2e-3)


def test_upside_down_differs_from_upright_by_half_a_turn_of_the_wrist(arm: ArmModel) -> None:
    upright = arm.ik(GraspTarget((0.5, 0.1, 0.196), GraspKind.SIDE))
    inverted = arm.ik(GraspTarget((0.5, 0.1, 0.196), GraspKind.SIDE_UPSIDE_DOWN))
    assert upright.q is not None
    assert inverted.q is not None
    assert np.allclose(upright.q[:4], inverted.q[:4], atol=1e-4)
    assert abs(inverted.q[4] - upright.q[4]) == pytest.approx(math.pi, abs=1e-3)


def test_a_seed_near_a_solution_returns_that_solution(arm: ArmModel) -> None:
    q = np.array([0.3, -1.0, 1.6, -2.0, -1.2])
    position, _ = arm.fk(q)
    result = arm.ik(GraspTarget(tuple(position)), seeds=[q + 0.02])
    assert result.q is not None
    assert np.allclose(result.q, q, atol=0.05)


def test_target_beyond_reach_is_refused_with_the_distance(arm: ArmModel) -> None:
    result = arm.ik(GraspTarget((0.9, 0.0, 0.06), GraspKind.SIDE))
    assert not result.ok
    assert result.q is None
    assert result.reason == (
        "out of reach for a side grasp: the wrist would be 0.750 m from the shoulder, the arm reaches 0.578 m"
    )


def test_position_beyond_reach_is_refused_with_the_distance(arm: ArmModel) -> None:
    result = arm.ik(GraspTarget((0.0, 0.0, 0.9)))
    assert result.reason == "out of reach: 0.840 m from the shoulder, the arm reaches 0.728 m"


def test_nan_target_is_refused(arm: ArmModel) -> None:
    result = arm.ik(GraspTarget((math.nan, 0.1, 0.06), GraspKind.SIDE))
    assert not result.ok
    assert result.reason == "target position is not finite: [nan, 0.1, 0.06]"


def test_side_grasp_too_close_to_the_base_names_the_joint_at_its_limit(arm: ArmModel) -> None:
    result = arm.ik(GraspTarget((0.25, 0.0, 0.06), GraspKind.SIDE))
    assert not result.ok
    assert result.reason == (
        "no solution within the joint limits (elbow up: wrist_lift=-3.0697 rad is outside [-2.8000, 2.8000]; "
        "elbow down: shoulder_lift=1.2972 rad is outside [-2.0000, 0.3000])"
    )


def test_limit_violations_name_the_joint_and_range(arm: ArmModel) -> None:
    assert arm.limit_violations([0.0, 1.0, 0.0, 0.0, 0.0]) == [
        "shoulder_lift=1.0000 rad is outside [-2.0000, 0.3000]"
    ]
