"""What every candidate mug for a slot shares is decided once (``CyclePlanner.plan_for_slot``): a slot no mug
can be put down in, or none standing upright can be flipped for, is refused without planning a candidate,
and the answer is kept for the slot and tray. That shortcut must never change a plan: filling the slots of
a dataset in order gives what planning each candidate in turn gives (the search before the shortcut)."""

from __future__ import annotations

import dataclasses
import math
import pickle
from collections.abc import Sequence
from typing import Any

import pytest

from daemon.config import load_config
from description.cell import CellLayout
from description.thesis import MUG_TYPES
from planning.arm import ArmModel
from planning.arm.grasp import handle_facing_away_rad
from planning.interfaces import CyclePlan, MotionRefused, MugPose, StepKind, TraySlot
from planning.motion import CyclePlanner
from planning.placement import PlanOptions, cell_dataset_problem, plan
from sim.counter import dataset_counter

START_Q = (0.0, -1.2, 1.7, -2.0, -math.pi / 2)
MUG = MugPose("m1", "big", -0.10, 0.45, handle_yaw_rad=math.atan2(0.45, -0.10))
OTHER = MugPose("m2", "big", 0.10, 0.45, handle_yaw_rad=math.atan2(0.45, 0.10))
SLOT = TraySlot("m1", "big", 0.45, 0.05)


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


@pytest.fixture(scope="module")
def cell() -> CellLayout:
    return load_config().cell


def each_in_turn(
    planner: CyclePlanner,
    q: Sequence[float],
    slot: TraySlot,
    counter: Sequence[MugPose],
    placed: Sequence[TraySlot],
) -> tuple[MugPose, CyclePlan] | None:
    """The search without the shortcut: the named mug, then the others of its type nearest first."""
    named = [m for m in counter if m.mug_id == slot.mug_id]
    others = sorted(
        (m for m in counter if m.type == slot.type and m.mug_id != slot.mug_id),
        key=lambda m: (math.hypot(m.x_m, m.y_m), m.mug_id),
    )
    for mug in [*named, *others]:
        try:
            return mug, planner.plan_cycle(
                q, mug, dataclasses.replace(slot, mug_id=mug.mug_id), placed, counter=counter
            )
        except MotionRefused:
            continue
    return None


def same_plan(a: CyclePlan, b: CyclePlan) -> bool:
    def trajectory(step: object) -> object:
        t = getattr(step, "trajectory", None)
        return None if t is None else (t.positions.tobytes(), t.times.tobytes())

    return (a.mug_id, a.duration_s, a.energy_j, a.handle_yaw_rad) == (
        b.mug_id,
        b.duration_s,
        b.energy_j,
        b.handle_yaw_rad,
    ) and [(s.phase, s.kind, s.aperture_m, trajectory(s)) for s in a.steps] == [
        (s.phase, s.kind, s.aperture_m, trajectory(s)) for s in b.steps
    ]


# Dataset 4 (the full-size tray: many candidates per refused slot) takes tens of seconds: not the fast loop.
@pytest.mark.parametrize("dataset", [1, 2, 3, pytest.param(4, marks=pytest.mark.slow)])
def test_filling_a_dataset_slot_by_slot_plans_what_each_candidate_in_turn_plans(
    arm: ArmModel, cell: CellLayout, dataset: int
) -> None:
    problem = cell_dataset_problem(cell, dataset)
    tray = dataset_counter(dataset, cell, MUG_TYPES).tray  # the full-size tray for dataset 4
    planner = CyclePlanner(arm, dataclasses.replace(cell, tray=tray), MUG_TYPES)
    reference = CyclePlanner(arm, dataclasses.replace(cell, tray=tray), MUG_TYPES)
    layout = plan(problem, PlanOptions(method="bh"))
    counter = {}
    for m in problem.mugs:
        x, y = m.x_mm / 1000.0, m.y_mm / 1000.0
        counter[m.id] = MugPose(m.id, m.type, x, y, handle_yaw_rad=handle_facing_away_rad(x, y))
    q: Sequence[float] = START_Q
    placed: list[TraySlot] = []
    outcomes = []
    for spot in sorted(layout.placed, key=lambda p: p.order)[:12]:
        cx, cy = problem.to_world_mm(*problem.brim_centre_on_tray(spot.type, spot.x_mm, spot.y_mm))
        slot = TraySlot(spot.id, spot.type, cx / 1000.0, cy / 1000.0, spot.rotated)
        expected = each_in_turn(reference, q, slot, list(counter.values()), placed)
        if expected is None:
            with pytest.raises(MotionRefused, match=rf"^slot for {spot.id}: no {spot.type} mug can be moved"):
                planner.plan_for_slot(q, slot, list(counter.values()), placed)
            outcomes.append("refused")
            continue
        mug, cycle = planner.plan_for_slot(q, slot, list(counter.values()), placed)
        assert mug == expected[0]
        assert same_plan(cycle, expected[1])
        outcomes.append("planned")
        counter.pop(mug.mug_id)
        placed.append(TraySlot(mug.mug_id, mug.type, slot.x_m, slot.y_m))
        moves = [s for s in cycle.steps if s.kind is StepKind.MOVE and s.trajectory is not None]
        q = tuple(float(v) for v in moves[-1].trajectory.positions[-1])  # type: ignore[union-attr]
    assert "planned" in outcomes
    if dataset == 4:  # the full-size tray: slots beyond the arm's reach, blocked and flipped-mug refusals
        assert "refused" in outcomes


def test_a_slot_no_mug_can_be_put_down_in_is_refused_without_planning_a_candidate(
    arm: ArmModel, cell: CellLayout, monkeypatch: pytest.MonkeyPatch
) -> None:
    planner = CyclePlanner(arm, cell, MUG_TYPES)
    tried: list[str] = []
    plan_cycle = planner.plan_cycle

    def counted(q: Sequence[float], mug: MugPose, *args: Any, **kwargs: Any) -> CyclePlan:
        tried.append(mug.mug_id)
        return plan_cycle(q, mug, *args, **kwargs)

    monkeypatch.setattr(planner, "plan_cycle", counted)
    on_it = [TraySlot("m4", "small", 0.45, 0.05)]  # a placed mug stands where the slot is
    with pytest.raises(MotionRefused, match=r"^slot for m1: no big mug can be moved there \(place\.") as e:
        planner.plan_for_slot(START_Q, SLOT, [MUG, OTHER], on_it)
    assert tried == []
    assert "the held mug m1 would hit mug m4" in str(e.value)
    assert e.value.blockers == {"m4"}  # the counter's mugs play no part: moving them cannot help


def test_what_a_slot_shares_is_worked_out_once_per_slot_and_tray(
    arm: ArmModel, cell: CellLayout, monkeypatch: pytest.MonkeyPatch
) -> None:
    planner = CyclePlanner(arm, cell, MUG_TYPES)
    worked_out: list[TraySlot] = []
    shared = planner._shared_motions_refused

    def counted(slot: TraySlot, *args: Any) -> object:
        worked_out.append(slot)
        return shared(slot, *args)

    monkeypatch.setattr(planner, "_shared_motions_refused", counted)
    on_it = [TraySlot("m4", "small", 0.45, 0.05)]
    for _ in range(2):
        with pytest.raises(MotionRefused):
            planner.plan_for_slot(START_Q, SLOT, [MUG, OTHER], on_it)
    mug, _ = planner.plan_for_slot(START_Q, SLOT, [MUG, OTHER], [])  # the tray changed: worked out again
    assert mug == MUG
    assert worked_out == [SLOT, SLOT]


def test_a_planner_sent_to_another_process_leaves_what_it_remembers_behind(
    arm: ArmModel, cell: CellLayout
) -> None:
    planner = CyclePlanner(arm, cell, MUG_TYPES)
    planner.plan_for_slot(START_Q, SLOT, [MUG], [])
    assert planner._shared
    assert pickle.loads(pickle.dumps(planner))._shared == {}
