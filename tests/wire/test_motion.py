"""Motion plans on the wire (``input/motion``'s ``result``): every planner call's result reads back through
the typed views as what was recorded, bit for bit; a result that is not one is refused with one line naming
the field; and the views are no topic's type, so ``input/motion``'s schema keeps ``result`` an object."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from drivers.interfaces import JointTrajectory
from planning.interfaces import CyclePlan, MugPose, Step, StepKind
from wire.messages import TOPICS, Motion
from wire.motion import (
    BadMotionRecord,
    CyclePlanView,
    MugPoseView,
    SlotResultView,
    StepView,
    TrajectoryView,
    result_from_json,
    result_json,
)
from wire.schemas import message_schema

finite = st.floats(-1e6, 1e6, allow_nan=False)
names = st.lists(st.sampled_from(["a", "b", "c", "d"]), min_size=1, max_size=4, unique=True)


@st.composite
def trajectories(draw: st.DrawFn) -> JointTrajectory:
    joints = draw(names)
    n = draw(st.integers(0, 5))
    times = draw(arrays(np.float64, n, elements=finite))
    positions = draw(arrays(np.float64, (n, len(joints)), elements=finite))
    return JointTrajectory(tuple(joints), times, positions, label=draw(st.text(max_size=5)))


@st.composite
def cycle_plans(draw: st.DrawFn) -> CyclePlan:
    steps = []
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(list(StepKind)))
        traj = draw(trajectories()) if kind is StepKind.MOVE else None
        aperture = draw(st.none() | finite) if kind is StepKind.OPEN else None
        steps.append(
            Step(draw(st.sampled_from(["side_grasp.approach", "place.release"])), kind, traj, aperture)
        )
    return CyclePlan(
        mug_id=draw(st.text(max_size=4)),
        steps=tuple(steps),
        duration_s=draw(finite),
        energy_j=draw(finite),
        handle_yaw_rad=draw(st.none() | finite),
    )


mug_poses = st.builds(
    MugPose,
    mug_id=st.text(max_size=4),
    type=st.sampled_from(["cup", "big"]),
    x_m=finite,
    y_m=finite,
    handle_yaw_rad=finite,
    upside_down=st.booleans(),
    handle_seen=st.booleans(),
)


def _through_json(call: str, result: object) -> object:
    """What a replay reads of a recorded result: its JSON text decoded again."""
    return result_from_json(call, json.loads(json.dumps(result_json(call, result))))


def _same_trajectory(a: JointTrajectory, b: JointTrajectory) -> None:
    assert (a.names, a.label) == (b.names, b.label)
    assert np.asarray(a.times).tobytes() == np.asarray(b.times).tobytes()
    assert np.asarray(a.positions).tobytes() == np.asarray(b.positions).tobytes()


def _same_plan(a: CyclePlan, b: CyclePlan) -> None:
    assert (a.mug_id, a.duration_s, a.energy_j, a.handle_yaw_rad) == (
        b.mug_id,
        b.duration_s,
        b.energy_j,
        b.handle_yaw_rad,
    )
    assert len(a.steps) == len(b.steps)
    for s, t in zip(a.steps, b.steps, strict=True):
        assert (s.phase, s.kind, s.aperture_m) == (t.phase, t.kind, t.aperture_m)
        assert isinstance(t.kind, StepKind)
        assert (s.trajectory is None) == (t.trajectory is None)
        if s.trajectory is not None and t.trajectory is not None:
            _same_trajectory(s.trajectory, t.trajectory)


@given(traj=trajectories())
def test_a_trajectory_reads_back_bit_for_bit(traj: JointTrajectory) -> None:
    back = _through_json("plan_move", traj)
    assert isinstance(back, JointTrajectory)
    _same_trajectory(traj, back)


@given(plan=cycle_plans())
def test_a_cycle_plan_reads_back_as_recorded(plan: CyclePlan) -> None:
    back = _through_json("plan_cycle", plan)
    assert isinstance(back, CyclePlan)
    _same_plan(plan, back)


@given(mug=mug_poses, plan=cycle_plans())
def test_a_slot_plan_reads_back_with_its_mug(mug: MugPose, plan: CyclePlan) -> None:
    back = _through_json("plan_for_slot", (mug, plan))
    assert isinstance(back, tuple)
    back_mug, back_plan = back
    assert back_mug == mug
    assert all(isinstance(getattr(back_mug, f), float) for f in ("x_m", "y_m", "handle_yaw_rad"))
    _same_plan(plan, back_plan)


def test_a_result_with_keys_a_later_version_adds_still_reads() -> None:
    traj = JointTrajectory(("a",), np.array([0.0, 1.0]), np.array([[0.5], [0.25]]))
    doc = result_json("plan_cycle", CyclePlan("m1", (Step("p", StepKind.MOVE, traj),), 1.0, 2.0))
    doc["new_field"] = 1
    doc["steps"][0]["trajectory"]["frame"] = "world"
    back = result_from_json("plan_cycle", doc)
    assert isinstance(back, CyclePlan)
    assert back.steps[0].trajectory is not None
    assert back.steps[0].trajectory.positions.tolist() == [[0.5], [0.25]]


GOOD_STEP = {"phase": "p", "kind": "close"}
PLAN = {"mug_id": "m1", "steps": [GOOD_STEP], "duration_s": 1.0, "energy_j": 2.0, "handle_yaw_rad": None}
MUG = {"mug_id": "m1", "type": "cup", "x_m": 0.1, "y_m": 0.2, "handle_yaw_rad": 0.0}
TRAJ = {"names": ["a"], "encoding": "float64_le_base64", "times": "", "positions": "", "label": ""}


@pytest.mark.parametrize(
    ("call", "doc", "message"),
    [
        ("plan_cycle", [1], "plan_cycle result: expected a table, got a list"),
        ("plan_cycle", {**PLAN, "steps": None}, "plan_cycle result.steps: expected a list, got None"),
        ("plan_cycle", {"steps": [], "energy_j": 1.0}, "plan_cycle result.duration_s: missing"),
        ("plan_cycle", {**PLAN, "energy_j": "2"}, "plan_cycle result.energy_j: expected a number, got '2'"),
        ("plan_cycle", {**PLAN, "energy_j": True}, "plan_cycle result.energy_j: expected a number, got true"),
        (
            "plan_cycle",
            {**PLAN, "steps": [{"kind": "jump"}]},
            "plan_cycle result.steps[0].kind: 'jump' is not one of move, close, open",
        ),
        (
            "plan_cycle",
            {**PLAN, "steps": [{**GOOD_STEP, "aperture_m": "wide"}]},
            "plan_cycle result.steps[0].aperture_m: expected a number, got 'wide'",
        ),
        ("plan_move", None, "plan_move result: expected a table, got None"),
        ("plan_move", {**TRAJ, "names": [1]}, "plan_move result.names[0]: expected a string, got 1"),
        ("plan_move", {**TRAJ, "times": 3}, "plan_move result.times: expected a string, got 3"),
        ("plan_move", {**TRAJ, "times": "AAAA"}, "a trajectory's times is 3 bytes, not whole float64 values"),
        (
            "plan_move",
            {**TRAJ, "times": "AAAAAAAAAAA="},
            "a trajectory has 1 times and 0 positions for 1 joints",
        ),
        ("plan_for_slot", {"plan": PLAN}, "plan_for_slot result.mug: missing"),
        (
            "plan_for_slot",
            {"mug": {**MUG, "y_m": None}, "plan": PLAN},
            "plan_for_slot result.mug.y_m: expected a number, got None",
        ),
        ("plan_fly", {}, "unknown planner call 'plan_fly'"),
    ],
)
def test_a_result_that_is_not_one_is_refused_in_one_line(call: str, doc: object, message: str) -> None:
    with pytest.raises(BadMotionRecord) as e:
        result_from_json(call, doc)
    assert str(e.value) == message


def test_the_views_are_no_topic_type_and_the_motion_schema_keeps_result_an_object() -> None:
    views = {TrajectoryView, StepView, CyclePlanView, MugPoseView, SlotResultView}
    assert not views & set(TOPICS.values())
    properties = message_schema(Motion)["properties"]
    assert isinstance(properties, dict)
    assert properties["result"] == {
        "type": "object",
        "description": "the plan: a cycle plan, {mug, plan} or a trajectory (float64 base64 arrays)",
    }
