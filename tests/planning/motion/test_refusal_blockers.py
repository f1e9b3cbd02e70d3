"""A refused motion names the mugs that blocked it (``MotionRefused.blockers``), so the job can tell when
trying again could succeed; the names survive the trip back from a planning process."""

from __future__ import annotations

import math
import pickle

import pytest

from daemon.config import load_config
from description.thesis import MUG_TYPES
from planning.arm import ArmModel
from planning.interfaces import MotionRefused, MugPose, TraySlot
from planning.motion import CyclePlanner
from planning.motion.collision import Collision

START_Q = (0.0, -1.2, 1.7, -2.0, -math.pi / 2)
SLOT = TraySlot("m1", "big", 0.45, 0.05)
BEHIND = MugPose("m1", "big", 0.064, 0.529)
IN_FRONT = MugPose("m2", "small", 0.064, 0.415)


@pytest.fixture(scope="module")
def planner() -> CyclePlanner:
    return CyclePlanner(ArmModel.load(), load_config().cell, MUG_TYPES)


def test_an_approach_through_another_mug_is_blocked_by_that_mug(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^side_grasp.approach: the gripper would hit mug m2") as e:
        planner.plan_cycle(START_Q, BEHIND, SLOT, [], counter=[IN_FRONT])
    # Straight from above, the open gripper would meet the mug itself: it is part of the refusal too.
    assert e.value.blockers == {"m1", "m2"}


def test_a_slot_no_candidate_reaches_is_blocked_by_what_blocked_each(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"^slot for m1: no big mug can be moved there") as e:
        planner.plan_for_slot(START_Q, SLOT, [BEHIND, IN_FRONT], [])
    assert e.value.blockers == {"m1", "m2"}


def test_a_mug_out_of_reach_is_blocked_by_no_mug(planner: CyclePlanner) -> None:
    with pytest.raises(MotionRefused, match=r"unreachable: out of reach") as e:
        planner.plan_cycle(START_Q, MugPose("m1", "big", 0.0, 0.85), SLOT, [])
    assert e.value.blockers == frozenset()


def test_a_collision_names_the_mug_it_meets_and_no_mug_for_a_wall() -> None:
    hit = Collision("the gripper would hit mug m7 handle (pose 3 of 9)", "mug m7 handle")
    assert (hit.mug_ids, str(hit)) == (frozenset({"m7"}), "the gripper would hit mug m7 handle (pose 3 of 9)")
    assert Collision("the gripper would hit the tray's near wall", "the tray's near wall").mug_ids == set()


def test_blockers_survive_pickling_as_from_a_planning_process() -> None:
    refused = MotionRefused.combining(
        "slot for m1: no big mug can be moved there",
        [MotionRefused("a", blockers=["m2"]), MotionRefused("b"), MotionRefused("c", blockers=["m3"])],
    )
    back = pickle.loads(pickle.dumps(refused))
    assert (str(back), back.blockers) == ("slot for m1: no big mug can be moved there", {"m2", "m3"})
