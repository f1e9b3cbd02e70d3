"""The pick-flip-place cycle: phases, continuity, servo limits, geometry at the key poses, and refusals."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from daemon.config import load_config
from description import thesis
from description.cell import CellLayout
from description.thesis import MUG_TYPES
from planning.arm import ArmModel, GraspKind, GraspTarget
from planning.arm.grasp import lateral_offset_m, reach_past_axis_m
from planning.interfaces import CyclePlan, MotionPlanner, MotionRefused, MugPose, StepKind, TraySlot
from planning.motion import CyclePlanner

START_Q = (0.0, -1.2, 1.7, -2.0, -math.pi / 2)
TRAY_FLOOR = 0.006
# The held mug's bottom 3 cm (+5 mm margin) above the tallest mug (106 mm) standing on the tray's base.
CARRY_Z = 0.106 + TRAY_FLOOR + 0.03 + 0.06 + 0.005
PHASES = [
    ("side_grasp.approach", StepKind.OPEN),
    ("side_grasp.approach", StepKind.MOVE),
    ("side_grasp.approach", StepKind.MOVE),
    ("side_grasp.approach", StepKind.MOVE),
    ("side_grasp.approach", StepKind.MOVE),
    ("side_grasp.close", StepKind.CLOSE),
    ("side_grasp.lift", StepKind.MOVE),
    ("flip.transit", StepKind.MOVE),
    ("flip.turn", StepKind.MOVE),
    ("flip.set_down", StepKind.MOVE),
    ("flip.set_down", StepKind.MOVE),
    ("flip.release", StepKind.OPEN),
    ("flip.regrasp", StepKind.MOVE),
    ("flip.regrasp", StepKind.MOVE),
    ("flip.regrasp", StepKind.MOVE),
    ("flip.regrasp", StepKind.MOVE),
    ("flip.regrasp", StepKind.MOVE),
    ("flip.close", StepKind.CLOSE),
    ("flip.lift", StepKind.MOVE),
    ("place.transit", StepKind.MOVE),
    ("place.descend", StepKind.MOVE),
    ("place.descend", StepKind.MOVE),
    ("place.release", StepKind.OPEN),
    ("place.retreat", StepKind.MOVE),
    ("place.retreat", StepKind.MOVE),
    ("place.retreat", StepKind.MOVE),
    ("place.retreat", StepKind.OPEN),
]


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


@pytest.fixture(scope="module")
def cell() -> CellLayout:
    return load_config().cell


@pytest.fixture(scope="module")
def planner(arm: ArmModel, cell: CellLayout) -> CyclePlanner:
    return CyclePlanner(arm, cell, MUG_TYPES)


# Handles point away from the arm, out of the side grasp's way (as the simulated cells set them out).
MUG = MugPose("m1", "big", -0.10, 0.45, handle_yaw_rad=math.atan2(0.45, -0.10))
NEIGHBOURS = [MugPose("m2", "small", 0.08, 0.45), MugPose("m3", "big", -0.10, 0.58)]
SLOT = TraySlot("m1", "big", 0.45, 0.05)
PLACED = [TraySlot("m4", "small", 0.45, -0.06), TraySlot("m5", "big", 0.60, 0.05)]


@pytest.fixture(scope="module")
def plan(planner: CyclePlanner) -> CyclePlan:
    return planner.plan_cycle(START_Q, MUG, SLOT, PLACED, counter=NEIGHBOURS)


def test_planner_implements_the_motion_planner_protocol(planner: CyclePlanner) -> None:
    assert isinstance(planner, MotionPlanner)


def test_cycle_steps_follow_the_statechart_substates(plan: CyclePlan) -> None:
    assert [(s.phase, s.kind) for s in plan.steps] == PHASES
    assert all((s.trajectory is None) == (s.kind is not StepKind.MOVE) for s in plan.steps)
    assert plan.steps_for("flip")[0].phase == "flip.transit"


def test_moves_are_continuous_from_the_start_pose(plan: CyclePlan) -> None:
    q = np.array(START_Q)
    for step in plan.steps:
        if step.trajectory is None:
            continue
        assert np.allclose(step.trajectory.positions[0], q, atol=1e-9), step.phase
        q = step.trajectory.positions[-1]


def test_trajectories_are_sampled_at_the_control_rate_within_the_servo_limits(
    plan: CyclePlan, arm: ArmModel
) -> None:
    for step in plan.steps:
        traj = step.trajectory
        if traj is None:
            continue
        assert traj.names == arm.joint_names
        assert traj.times[0] == 0.0
        dt = np.diff(traj.times)
        assert np.allclose(dt[:-1], 1 / 50.0)
        assert 0 < dt[-1] <= 1 / 50.0 + 1e-9
        assert np.all(traj.positions >= arm.lower - 1e-9)
        assert np.all(traj.positions <= arm.upper + 1e-9)
        v = np.diff(traj.positions, axis=0) / dt[:, None]
        assert np.all(np.abs(v) <= arm.max_velocity * 1.02), step.phase
        if len(dt) > 2:
            a = np.diff(v[:-1], axis=0) / dt[1:-1, None]
            assert np.all(np.abs(a) <= arm.max_acceleration * 1.05), step.phase


def _end_of(plan: CyclePlan, phase: str) -> np.ndarray:
    moves = [s for s in plan.steps if s.phase == phase and s.trajectory is not None]
    assert moves[-1].trajectory is not None
    return np.asarray(moves[-1].trajectory.positions[-1])


def _big_mug_axis(arm: ArmModel, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Where a big mug's axis is (x, y) for the grasp point at ``position`` with ``rotation``."""
    reach = reach_past_axis_m(MUG_TYPES["big"], arm.gripper)
    lateral = lateral_offset_m(MUG_TYPES["big"], arm.gripper)
    return np.asarray(position[:2] + lateral * rotation[:2, 1] - reach * rotation[:2, 2])


def test_grasp_pose_holds_the_mug_axis_six_centimetres_up(plan: CyclePlan, arm: ArmModel) -> None:
    position, rotation = arm.fk(_end_of(plan, "side_grasp.approach"))
    axis = _big_mug_axis(arm, position, rotation)
    assert np.allclose(axis, [MUG.x_m, MUG.y_m], atol=1e-3)
    assert position[2] == pytest.approx(thesis.GRASP_HEIGHT_M, abs=1e-3)
    assert rotation[2, 0] == pytest.approx(-1.0, abs=1e-3)  # side grasp: the grasp frame's x points down


def test_flip_turns_the_wrist_by_half_a_turn_above_the_flip_area(plan: CyclePlan, arm: ArmModel) -> None:
    turn = next(s for s in plan.steps if s.phase == "flip.turn").trajectory
    assert turn is not None
    before, after = turn.positions[0], turn.positions[-1]
    assert abs(after[4] - before[4]) == pytest.approx(math.pi, abs=2e-3)
    assert np.allclose(before[:4], after[:4], atol=2e-3)
    position, _ = arm.fk(after)
    assert position[2] == pytest.approx(CARRY_Z, abs=1e-3)


def test_release_on_the_tray_puts_the_inverted_mug_on_its_slot(plan: CyclePlan, arm: ArmModel) -> None:
    position, rotation = arm.fk(_end_of(plan, "place.descend"))
    axis = _big_mug_axis(arm, position, rotation)
    assert np.allclose(axis, [SLOT.x_m, SLOT.y_m], atol=1e-3)
    assert rotation[2, 0] == pytest.approx(1.0, abs=1e-3)  # upside down: x up
    # The brim, 6 cm below the grasp point, hangs just above the tray's base.
    assert 0.0 < position[2] - thesis.PLACE_HEIGHT_M - TRAY_FLOOR <= 0.01


def test_carried_mug_stays_at_carry_height_in_transit(plan: CyclePlan, arm: ArmModel) -> None:
    for phase in ("flip.transit", "place.transit"):
        traj = next(s for s in plan.steps if s.phase == phase).trajectory
        assert traj is not None
        heights = [arm.fk(q)[0][2] for q in traj.positions[::5]]
        assert np.allclose(heights, CARRY_Z, atol=1e-3), phase


def test_cycle_time_and_energy_are_predicted(plan: CyclePlan) -> None:
    moving = sum(s.trajectory.duration for s in plan.steps if s.trajectory is not None)
    assert plan.duration_s == pytest.approx(moving + 2 * 1.0 + 4 * 0.6)
    assert plan.duration_s < thesis.MAX_SECONDS_PER_MUG
    standby_w = thesis.SUPPLY_VOLTAGE_V * (4 * 0.1 + 2 * 0.05)
    assert plan.energy_j > standby_w * plan.duration_s


def test_nan_start_pose_is_refused(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^start_q: joint angles must be finite, got \[nan, "):
        planner.plan_cycle((math.nan, -1.2, 1.7, -2.0, 0.0), MUG, SLOT, [])


def test_start_pose_beyond_a_joint_limit_is_refused(planner: CyclePlanner) -> None:
    with pytest.raises(
        MotionRefused, match=r"^start_q: shoulder_lift=1.0000 rad is outside \[-2.0000, 0.3000\]$"
    ):
        planner.plan_cycle((0.0, 1.0, 1.7, -2.0, 0.0), MUG, SLOT, [])


def test_unknown_mug_type_is_refused(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^mug m9: unknown mug type 'teacup' \(catalogue: big, small\)$"):
        planner.plan_cycle(
            START_Q, MugPose("m9", "teacup", 0.0, 0.45), TraySlot("m9", "teacup", 0.45, 0.0), []
        )


def test_slot_outside_the_tray_is_refused(planner: CyclePlanner) -> None:
    with pytest.raises(
        MotionRefused, match=r"^slot of m1 at \(0.700, 0.000\) m puts the mug outside the tray"
    ):
        planner.plan_cycle(START_Q, MUG, TraySlot("m1", "big", 0.70, 0.0), [])


def test_rotated_slot_is_refused_because_the_arm_has_no_wrist_yaw(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^slot for m1 is rotated: the arm has no wrist yaw"):
        planner.plan_cycle(START_Q, MUG, TraySlot("m1", "big", 0.45, 0.0, rotated=True), [])


def test_mug_beyond_reach_is_refused_with_the_reason(planner: CyclePlanner) -> None:
    with pytest.raises(
        MotionRefused, match=r"^side_grasp.approach: \(.*\) m unreachable: out of reach for a side"
    ):
        planner.plan_cycle(START_Q, MugPose("m1", "big", 0.0, 0.85), SLOT, [])


def test_slot_on_top_of_a_placed_mug_is_refused_as_a_collision(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^place\.(transit|descend): the held mug m1 would hit mug m4"):
        planner.plan_cycle(START_Q, MUG, SLOT, [TraySlot("m4", "small", 0.45, 0.05)])


def test_a_mug_in_the_approach_path_is_refused_as_a_collision(planner: CyclePlanner) -> None:
    blocker = MugPose("m7", "big", -0.085, 0.36)  # on the line from the base to the target, 9 cm closer
    with pytest.raises(MotionRefused, match=r"^side_grasp.approach: the gripper would hit mug m7"):
        planner.plan_cycle(START_Q, MUG, SLOT, [], counter=[blocker])


def test_plan_move_stays_within_limits_and_ends_on_the_goal(planner: CyclePlanner, arm: ArmModel) -> None:
    goal = (0.5, -1.0, 1.5, -2.0, -1.0)
    traj = planner.plan_move(START_Q, goal, label="park")
    assert traj.label == "park"
    assert np.allclose(traj.positions[-1], goal)
    v = np.diff(traj.positions, axis=0) / np.diff(traj.times)[:, None]
    assert np.all(np.abs(v) <= arm.max_velocity * 1.02)


def test_plan_move_refuses_a_goal_beyond_the_limits(planner: CyclePlanner) -> None:
    with pytest.raises(
        MotionRefused, match=r"^goal_q: wrist_turn=3.0000 rad is outside \[-2.6180, 2.6129\]$"
    ):
        planner.plan_move(START_Q, (0.0, -1.2, 1.7, -2.0, 3.0), label="park")


def test_plan_move_refuses_a_pose_below_the_counter(planner: CyclePlanner) -> None:
    with pytest.raises(
        MotionRefused, match=r"^park: the (gripper would touch the counter|.* joint would go below)"
    ):
        planner.plan_move(START_Q, (0.0, 0.3, 0.5, 0.0, 0.0), label="park")


def test_a_blocked_mug_is_swapped_for_a_reachable_one_of_its_type(planner: CyclePlanner) -> None:
    behind = MugPose("m1", "big", 0.064, 0.529)
    in_front = MugPose("m2", "big", 0.064, 0.415)
    mug, cycle = planner.plan_for_slot(START_Q, SLOT, [behind, in_front], [])
    assert mug == in_front
    assert cycle.mug_id == "m2"


def test_plan_for_slot_lists_why_no_mug_of_the_type_works(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^slot for m1: no big mug can be moved there \(m1: side_grasp"):
        planner.plan_for_slot(START_Q, SLOT, [MugPose("m1", "big", 0.0, 0.85)], [])


def test_plan_for_slot_without_a_mug_of_the_type_says_so(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^slot for m1: no big mug left on the counter$"):
        planner.plan_for_slot(START_Q, SLOT, [MugPose("m2", "small", 0.064, 0.415)], [])


def test_a_mug_close_to_the_base_is_taken_from_above(planner: CyclePlanner, arm: ArmModel) -> None:
    near = MugPose("m1", "big", 0.064, 0.415)
    cycle = planner.plan_cycle(START_Q, near, SLOT, [])
    approach = [s.trajectory for s in cycle.steps_for("side_grasp") if s.phase == "side_grasp.approach"]
    assert approach[-1] is not None
    start, _ = arm.fk(approach[-1].positions[0])
    end, _ = arm.fk(approach[-1].positions[-1])
    # Backing off 6 cm towards the base is out of the side-grasp ring this close in: the last move is short.
    assert float(np.linalg.norm(end - start)) < 0.035


def test_a_mug_already_upside_down_skips_the_flip(planner: CyclePlanner, arm: ArmModel) -> None:
    inverted = MugPose("m1", "big", -0.10, 0.45, upside_down=True)
    cycle = planner.plan_cycle(START_Q, inverted, SLOT, [])
    assert cycle.steps_for("flip") == ()
    grasp = [s for s in cycle.steps if s.phase == "side_grasp.approach"][-1].trajectory
    assert grasp is not None
    _, rotation = arm.fk(grasp.positions[-1])
    assert rotation[2, 0] == pytest.approx(1.0, abs=1e-3)  # taken with the upside-down grasp


def test_a_calibration_correction_moves_the_commanded_grasp(arm: ArmModel, cell: CellLayout) -> None:
    from planning.arm.calibration import FEATURES, PositionCorrection

    # The real arm reaches 1 cm further along x than commanded: the planner commands 1 cm short.
    offset = tuple(0.01 if f == "1" else 0.0 for f in FEATURES)
    zero = tuple(0.0 for _ in FEATURES)
    corrected = CyclePlanner(arm, cell, MUG_TYPES, correction=PositionCorrection((offset, zero, zero)))
    cycle = corrected.plan_cycle(START_Q, MUG, SLOT, [])
    position, _ = arm.fk(_end_of(cycle, "side_grasp.approach"))
    plain, _ = arm.fk(_end_of(_plan_without_correction(arm, cell), "side_grasp.approach"))
    assert position[0] == pytest.approx(plain[0] - 0.01, abs=1e-3)
    assert position[1] == pytest.approx(plain[1], abs=1e-3)


def _plan_without_correction(arm: ArmModel, cell: CellLayout) -> CyclePlan:
    return CyclePlanner(arm, cell, MUG_TYPES).plan_cycle(START_Q, MUG, SLOT, [])


def _opens(cycle: CyclePlan) -> list[tuple[str, float | None]]:
    return [(s.phase, s.aperture_m) for s in cycle.steps if s.kind is StepKind.OPEN]


def test_the_jaw_lets_go_on_the_tray_opening_only_a_little_and_opens_fully_at_carry_height(
    plan: CyclePlan, arm: ArmModel
) -> None:
    (approach, full_first), (flip, full_at_flip), (release, jaw), (retreat, full_after) = _opens(plan)
    assert (approach, full_first) == ("side_grasp.approach", None)  # whatever the jaw was left at
    assert (flip, full_at_flip) == ("flip.release", None)  # nothing stands near the flip area
    assert release == "place.release"
    assert jaw is not None
    assert 0.091 + 0.003 <= jaw <= 0.091 + 0.012  # wider than the big mug by more than the weld needs
    assert (retreat, full_after) == ("place.retreat", None)
    assert plan.steps[-1].kind is StepKind.OPEN
    position, _ = arm.fk(_end_of(plan, "place.retreat"))
    assert position[2] == pytest.approx(CARRY_Z, abs=1e-3)


def test_the_thumb_steps_off_the_brim_before_backing_away_and_onto_it_after_going_in(
    plan: CyclePlan, arm: ArmModel
) -> None:
    """Moving on the diagonal next to a mug drags or pushes it by the thumb's friction: the first move after
    each release is sideways only, away from the mug, and the last move of each approach sideways onto it."""
    for phase in ("place.retreat", "flip.regrasp"):
        first = next(s for s in plan.steps if s.phase == phase and s.trajectory is not None)
        assert first.trajectory is not None
        p0, rotation = arm.fk(first.trajectory.positions[0])
        p1, _ = arm.fk(first.trajectory.positions[-1])
        moved = np.asarray(p1) - np.asarray(p0)
        approach, mug_side = rotation[:, 2], rotation[:, 1]
        assert abs(float(moved @ approach)) < 5e-4, phase
        assert abs(moved[2]) < 5e-4, phase
        assert float(moved @ mug_side) < -0.002, phase  # away from the mug, on the thumb's side
    # ... and the last move of each approach brings the thumb sideways onto the brim.
    for phase in ("side_grasp.approach", "flip.regrasp"):
        last = [s for s in plan.steps if s.phase == phase and s.trajectory is not None][-1]
        assert last.trajectory is not None
        p0, rotation = arm.fk(last.trajectory.positions[0])
        p1, _ = arm.fk(last.trajectory.positions[-1])
        moved = np.asarray(p1) - np.asarray(p0)
        assert abs(float(moved @ rotation[:, 2])) < 5e-4, phase
        assert float(moved @ rotation[:, 1]) > 0.002, phase


def test_a_neighbour_a_centimetre_from_the_finger_gets_a_jaw_opened_only_a_little(
    planner: CyclePlanner, arm: ArmModel
) -> None:
    # A small mug 1 cm (the packing tolerance) to the right of the slot: the finger of the turned wrist, on
    # the mug's right, would open into it; it opens 6 mm and the slot is placed with the wrist turned.
    right = TraySlot("m4", "small", SLOT.x_m, SLOT.y_m - 0.0455 - 0.037 - 0.010)
    cycle = planner.plan_cycle(START_Q, MUG, SLOT, [right])
    position, rotation = arm.fk(_end_of(cycle, "place.descend"))
    assert rotation[2, 0] == pytest.approx(1.0, abs=1e-3)  # wrist turned: finger on the mug's right
    phase, aperture = _opens(cycle)[2]
    assert phase == "place.release"
    assert aperture == pytest.approx(0.091 + 0.006)
    axis = _big_mug_axis(arm, position, rotation)
    assert np.allclose(axis, [SLOT.x_m, SLOT.y_m], atol=1e-3)


def test_neighbours_a_centimetre_away_on_both_sides_still_take_the_mug(planner: CyclePlanner) -> None:
    gap = 0.0455 + 0.037 + 0.010
    tight = [
        TraySlot("m4", "small", SLOT.x_m, SLOT.y_m - gap),
        TraySlot("m5", "small", SLOT.x_m, SLOT.y_m + gap),
    ]
    cycle = planner.plan_cycle(START_Q, MUG, SLOT, tight)
    phase, aperture = _opens(cycle)[2]
    assert phase == "place.release"
    assert aperture == pytest.approx(0.091 + 0.006)


def test_neighbours_closer_than_the_thumb_on_both_sides_refuse_the_slot(planner: CyclePlanner) -> None:
    gap = 0.0455 + 0.037 + 0.003
    tight = [
        TraySlot("m4", "small", SLOT.x_m, SLOT.y_m - gap),
        TraySlot("m5", "small", SLOT.x_m, SLOT.y_m + gap),
    ]
    with pytest.raises(MotionRefused, match=r"^place\.descend: the gripper would hit mug m4"):
        planner.plan_cycle(START_Q, MUG, SLOT, tight)


def test_plan_move_refuses_to_sweep_through_a_mug_it_is_told_about(
    planner: CyclePlanner, arm: ArmModel
) -> None:
    low = arm.ik(GraspTarget((-0.10, 0.45, 0.09), GraspKind.SIDE))
    assert low.q is not None
    goal = low.q
    assert planner.plan_move(START_Q, goal, label="park").duration > 0
    with pytest.raises(MotionRefused, match=r"^park: the gripper would hit mug m8"):
        planner.plan_move(START_Q, goal, label="park", counter=[MugPose("m8", "big", -0.10, 0.47)])


def test_a_pickled_planner_plans_the_same_cycle(planner: CyclePlanner, plan: CyclePlan) -> None:
    import pickle

    copy = pickle.loads(pickle.dumps(planner))
    again = copy.plan_cycle(START_Q, MUG, SLOT, PLACED, counter=NEIGHBOURS)
    assert again.duration_s == pytest.approx(plan.duration_s)
    assert [s.phase for s in again.steps] == [s.phase for s in plan.steps]


def test_a_cycle_starting_with_the_open_gripper_around_a_mug_lifts_off_it_first(
    plan: CyclePlan, planner: CyclePlanner, arm: ArmModel
) -> None:
    """After a failed grasp the gripper opens where it is, still straddling that mug; the next cycle must
    not be refused for starting inside it (every later mug was, before)."""
    around_m1 = _end_of(plan, "side_grasp.approach")
    other = NEIGHBOURS[0]
    cycle = planner.plan_cycle(
        [float(v) for v in around_m1],
        other,
        TraySlot(other.mug_id, other.type, 0.45, 0.05),
        [],
        counter=[MUG, NEIGHBOURS[1]],
    )
    assert cycle.steps[0].kind is StepKind.OPEN  # opening around the mug it let go of is allowed
    first = cycle.steps[1].trajectory
    assert first is not None
    start_p, _ = arm.fk(first.positions[0])
    lifted = [arm.fk(q)[0] for q in first.positions[: len(first.positions) // 3]]
    assert all(np.hypot(p[0] - start_p[0], p[1] - start_p[1]) < 0.01 for p in lifted)  # straight up
    assert lifted[-1][2] > start_p[2] + 0.02


def test_the_handle_lands_on_the_tray_where_the_grasps_carry_it(planner: CyclePlanner) -> None:
    """No wrist yaw: pick, flip and regrasp mirror the handle's angle to the approach, so a handle facing away
    from the arm on the counter ends near the slot's bearing, and one along +x ends far round."""
    bearing_slot = math.atan2(SLOT.y_m, SLOT.x_m)
    cycle = planner.plan_cycle(START_Q, MUG, SLOT, [])
    assert cycle.handle_yaw_rad is not None
    assert abs(math.remainder(cycle.handle_yaw_rad - bearing_slot, math.tau)) < math.radians(8)
    along_x = planner.plan_cycle(START_Q, replace(MUG, handle_yaw_rad=0.0), SLOT, [])
    assert along_x.handle_yaw_rad is not None
    assert math.remainder(along_x.handle_yaw_rad - cycle.handle_yaw_rad, math.tau) == pytest.approx(
        math.atan2(MUG.y_m, MUG.x_m), abs=math.radians(2)
    )


def test_a_handle_that_would_land_in_a_placed_mug_is_refused(planner: CyclePlanner) -> None:
    # Handle along +x on the counter, straight ahead of the arm: on the tray it points about 100 degrees
    # round, into a mug placed 1 cm beside the slot on that side.
    beside = TraySlot("m4", "small", SLOT.x_m, SLOT.y_m + 0.0455 + 0.037 + 0.010)
    with pytest.raises(
        MotionRefused, match=r"^place: mug m1's handle would end at \d+ deg, 0 mm from the body of mug m4"
    ):
        planner.plan_cycle(START_Q, replace(MUG, handle_yaw_rad=0.0), SLOT, [beside])


def test_a_placed_mug_is_an_obstacle_with_its_handle_where_it_really_points(planner: CyclePlanner) -> None:
    # The same neighbour with its handle turned towards the slot (a known yaw) blocks it.
    beside = TraySlot("m4", "small", SLOT.x_m, SLOT.y_m + 0.0455 + 0.037 + 0.010)
    planner.plan_cycle(START_Q, MUG, SLOT, [beside])
    turned = replace(beside, handle_yaw_rad=-math.pi / 2)
    with pytest.raises(MotionRefused, match=r"mug m4"):
        planner.plan_cycle(START_Q, MUG, SLOT, [turned])


def test_handle_bars_that_cross_are_touching_and_apart_ones_measure_their_gap() -> None:
    from planning.motion.handle import segment_segment_m as _segment_segment_m

    bar = ((0.0, 0.0), (0.02, 0.0))
    assert _segment_segment_m(bar, ((0.01, -0.01), (0.01, 0.01))) == 0.0
    assert _segment_segment_m(bar, ((0.03, -0.01), (0.03, 0.01))) == pytest.approx(0.01)
    assert _segment_segment_m(bar, ((0.0, 0.004), (0.02, 0.004))) == pytest.approx(0.004)


def test_a_handle_the_camera_did_not_see_is_not_predicted_and_not_held_against_the_slot(
    planner: CyclePlanner,
) -> None:
    beside = TraySlot("m4", "small", SLOT.x_m, SLOT.y_m + 0.0455 + 0.037 + 0.010)
    guessed = replace(MUG, handle_yaw_rad=0.0, handle_seen=False)  # the same yaw refused above when seen
    cycle = planner.plan_cycle(START_Q, guessed, SLOT, [beside])
    assert cycle.handle_yaw_rad is None
