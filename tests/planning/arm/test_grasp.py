"""Side-grasp geometry of §4.3 (Eq 4.28-4.45) against the arm's own kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from description.thesis import BIG_MUG, SMALL_MUG
from planning.arm import ArmModel, GraspKind
from planning.arm.grasp import (
    PALM_GAP_M,
    lateral_offset_m,
    mug_axis_from_grasp,
    reach_past_axis_m,
    side_grasp,
    thesis_tray_limits,
)


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


@pytest.mark.parametrize("kind", [GraspKind.SIDE, GraspKind.SIDE_UPSIDE_DOWN])
@pytest.mark.parametrize("spec", [BIG_MUG, SMALL_MUG], ids=["big", "small"])
def test_the_held_mug_axis_is_where_the_mug_stands(arm: ArmModel, kind: GraspKind, spec: object) -> None:
    from description.thesis import MugSpec

    assert isinstance(spec, MugSpec)
    for mx, my in [(0.45, 0.0), (0.1, 0.45), (-0.2, 0.45), (0.5, -0.3)]:
        grasp = side_grasp(mx, my, spec, arm.gripper, z_m=0.06, kind=kind)
        result = arm.ik(grasp.target)
        assert result.ok, result.reason
        assert result.q is not None
        position, rotation = arm.fk(result.q)
        # The mug's axis is beside the approach (grasp y) and the finger tips reach past it (grasp z).
        reach = reach_past_axis_m(spec, arm.gripper)
        axis = position[:2] + lateral_offset_m(spec, arm.gripper) * rotation[:2, 1] - reach * rotation[:2, 2]
        assert np.allclose(axis, [mx, my], atol=1e-3)
        held = mug_axis_from_grasp(
            (grasp.target.position_m[0], grasp.target.position_m[1]), spec, arm.gripper, kind
        )
        assert np.allclose(held, [mx, my], atol=1e-9)


def test_palm_is_delta_mg_from_the_mug_at_angle_theta_off_the_approach(arm: ArmModel) -> None:
    g = side_grasp(0.4, 0.3, BIG_MUG, arm.gripper, z_m=0.06, kind=GraspKind.SIDE)
    palm_to_mug = np.array([0.4 - g.palm_xy_m[0], 0.3 - g.palm_xy_m[1]])
    r_m, w_g, l_g = 0.0455, arm.gripper.thumb_width_m, arm.gripper.finger_length_m
    assert g.delta_mg_m == pytest.approx(math.sqrt((r_m - w_g) ** 2 + l_g**2))  # Eq 4.30
    assert g.theta_rad == pytest.approx(math.atan((r_m - w_g) / l_g))  # Eq 4.32
    # Eq 4.30 and 4.36-4.37 with the finger tips reaching past the mug's axis: the mug is l_g - reach in
    # front of the palm and r_m - w_g to the side.
    reach = g.reach_m
    assert float(np.linalg.norm(palm_to_mug)) == pytest.approx(math.hypot(r_m - w_g, l_g - reach))
    angle = g.alpha_rad + math.atan2(r_m - w_g, l_g - reach)
    assert g.palm_xy_m[0] == pytest.approx(0.4 - math.hypot(r_m - w_g, l_g - reach) * math.cos(angle))
    assert g.palm_xy_m[1] == pytest.approx(0.3 - math.hypot(r_m - w_g, l_g - reach) * math.sin(angle))
    # Eq 4.28: the approach angle is the grasp point's bearing from the base.
    x_g, y_g, _ = g.target.position_m
    assert math.atan2(y_g, x_g) == pytest.approx(g.alpha_rad)
    # Eq 4.35: alpha' = beta' - gamma' for the side grasp, beta' + gamma' upside down.
    beta = math.atan2(0.3, 0.4)
    gamma = math.asin((r_m - w_g) / 0.5)
    assert g.alpha_rad == pytest.approx(beta - gamma)
    inverted = side_grasp(0.4, 0.3, BIG_MUG, arm.gripper, z_m=0.06, kind=GraspKind.SIDE_UPSIDE_DOWN)
    assert inverted.alpha_rad == pytest.approx(beta + gamma)
    angle = inverted.alpha_rad - math.atan2(r_m - w_g, l_g - reach)
    assert inverted.palm_xy_m[1] == pytest.approx(0.3 - math.hypot(r_m - w_g, l_g - reach) * math.sin(angle))


@pytest.mark.parametrize("spec", [BIG_MUG, SMALL_MUG], ids=["big", "small"])
def test_the_fingers_wrap_past_the_brim_centre_line_and_the_mug_clears_the_palm(
    arm: ArmModel, spec: object
) -> None:
    """Finger tips on the mug's widest line squeeze it out of the gripper; they must reach past it, yet
    leave the mug clear of the palm plate."""
    from description.thesis import MugSpec

    assert isinstance(spec, MugSpec)
    g = arm.gripper
    r = spec.diameter_mm / 2000.0
    reach = reach_past_axis_m(spec, g)
    assert reach >= 0.006  # at least 6 mm past the widest line
    palm_face = g.plate_thickness_m / 2
    assert g.finger_length_m - reach - r - palm_face >= PALM_GAP_M - 1e-9


def test_a_mug_on_the_shoulder_axis_cannot_be_side_grasped(arm: ArmModel) -> None:
    with pytest.raises(
        ValueError, match=r"^mug at \(0.010, 0.000\) is too close to the shoulder axis to grasp$"
    ):
        side_grasp(0.01, 0.0, BIG_MUG, arm.gripper, z_m=0.06)


def test_thesis_tray_limit_equations_widen_the_gripper_box_by_the_mug_geometry() -> None:
    delta, l_g = 0.017, 0.0572
    x_ltr, x_utr, y_ltr, y_utr = thesis_tray_limits(
        x_lg=0.40,
        x_ug=0.62,
        y_ug=0.40,
        y_ltr=0.132,
        delta_mg=math.hypot(delta, l_g),
        theta=math.atan2(delta, l_g),
        min_w_r=0.037,
        min_w_m=0.100,
    )
    assert y_ltr == 0.132
    assert x_utr - x_ltr > 0.62 - 0.40  # the tray is longer than the gripper's x range (22 cm vs 33.2 cm)
    assert y_utr > 0.40
