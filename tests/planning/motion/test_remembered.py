"""What the cycle planner remembers (``planning.motion.remembered``; IK, timed paths and gripper sweeps in
``Scene``/``CollisionWorld``) answers only a question asked exactly again, with exactly what working it out
afresh gives: the plan check's results may not change by being cheaper (issue 22)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest

from daemon.config import load_config
from description.thesis import MUG_TYPES
from planning.arm import ArmModel
from planning.arm.grasp import handle_facing_away_rad
from planning.interfaces import CyclePlan, MotionRefused, MugPose, TraySlot
from planning.motion import CyclePlanner
from planning.motion.collision import CollisionWorld, Cylinder
from planning.motion.remembered import Lru, RememberedCycles
from planning.placement.sequence import Sequenced, sequence

START_Q = (0.0, -1.4, 2.0, 1.0, -math.pi / 2)


def _mug(mug_id: str, kind: str, x: float, y: float) -> MugPose:
    return MugPose(mug_id, kind, x, y, handle_yaw_rad=handle_facing_away_rad(x, y))


FRONT = _mug("m1", "small", 0.376, 0.415)
BEHIND = _mug("m7", "big", 0.376, 0.529)  # its approach passes through FRONT
OTHER = _mug("m3", "small", 0.30, 0.36)
SLOTS = [TraySlot("m7", "big", 0.55, 0.08), TraySlot("m1", "small", 0.55, -0.08)]


@pytest.fixture(scope="module")
def planner() -> CyclePlanner:
    return CyclePlanner(ArmModel.load(), load_config().cell, MUG_TYPES)


def _changed(value: object) -> object:
    """Another value of a field's kind (a float by its last bit)."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, float):
        return float(np.nextafter(value, math.inf))
    if isinstance(value, str):
        return value + "x"
    if value is None:
        return 0.25
    raise AssertionError(f"no other value for {value!r}")


@pytest.mark.parametrize("which", ["mug", "slot", "on_tray", "counter"])
def test_every_field_of_every_argument_is_in_both_keys(which: str) -> None:
    slot = TraySlot("m1", "small", 0.55, -0.08, handle_yaw_rad=None)
    args: dict[str, object] = {"mug": FRONT, "slot": slot, "on_tray": (slot,), "counter": (FRONT, OTHER)}
    base = RememberedCycles.keys(START_Q, FRONT, slot, (slot,), (FRONT, OTHER))
    target = {"mug": FRONT, "slot": slot, "on_tray": slot, "counter": OTHER}[which]
    for field in dataclasses.fields(target):  # type: ignore[arg-type]
        other = dataclasses.replace(target, **{field.name: _changed(getattr(target, field.name))})  # type: ignore[type-var]
        a = dict(args)
        if which == "on_tray":
            a["on_tray"] = (other,)
        elif which == "counter":
            a["counter"] = (FRONT, other)
        else:
            a[which] = other
        mug = a["mug"]
        assert isinstance(mug, MugPose)
        keys = RememberedCycles.keys(START_Q, mug, a["slot"], a["on_tray"], a["counter"])  # type: ignore[arg-type]
        assert keys[0] != base[0], f"{which}.{field.name} not in the plan key"
        assert keys[1] != base[1], f"{which}.{field.name} not in the refusal key"


def test_a_start_differing_in_its_last_bit_or_by_the_sign_of_zero_is_another_question() -> None:
    slot = SLOTS[1]
    base = RememberedCycles.keys(START_Q, FRONT, slot, (), ())
    nudged = (float(np.nextafter(START_Q[0], 1.0)), *START_Q[1:])
    signed = (-0.0, *START_Q[1:])
    assert RememberedCycles.keys(nudged, FRONT, slot, (), ()) != base
    assert RememberedCycles.keys(signed, FRONT, slot, (), ()) != base


def test_a_plan_is_kept_by_the_set_of_other_counter_mugs_a_refusal_by_their_order() -> None:
    slot = SLOTS[1]
    one = RememberedCycles.keys(START_Q, FRONT, slot, (), (FRONT, OTHER, BEHIND))
    other_order = RememberedCycles.keys(START_Q, FRONT, slot, (), (BEHIND, OTHER))
    assert one[0] == other_order[0]  # the mug itself is no obstacle, the order does not change a plan
    assert one[1] != other_order[1]  # a refusal names the first obstacle met, which the order can change
    memory = RememberedCycles()
    memory.keep_refusal(one, MotionRefused("place.descend: the gripper would hit mug m7", blockers={"m7"}))
    assert memory.plan(other_order) is None
    for _ in range(2):  # raised afresh every time, with its text and blockers
        with pytest.raises(MotionRefused) as refused:
            memory.plan(one)
        assert str(refused.value) == "place.descend: the gripper would hit mug m7"
        assert refused.value.blockers == {"m7"}
        assert refused.value.__traceback__ is not None


def test_lru_keeps_the_most_recently_used_and_never_an_exception() -> None:
    memory: Lru[str, int] = Lru(2)
    assert memory.get("a", lambda: 1) == 1
    assert memory.get("b", lambda: 2) == 2
    assert memory.get("a", lambda: 10) == 1  # remembered, and now the most recent
    assert memory.get("c", lambda: 3) == 3  # "b" goes
    assert memory.get("b", lambda: 20) == 20

    def fails() -> int:
        raise MotionRefused("no")

    with pytest.raises(MotionRefused):
        memory.get("d", fails)
    assert memory.get("d", lambda: 4) == 4
    with pytest.raises(ValueError, match="limit"):
        Lru(0)


def _forgetting(planner: CyclePlanner) -> Callable[[], None]:
    def forget() -> None:
        planner.remembered.clear()
        planner.scene._forget()

    return forget


class _Afresh:
    """The planner, made to forget everything before each call: every answer worked out afresh."""

    def __init__(self, planner: CyclePlanner) -> None:
        self.planner = planner
        self.forget = _forgetting(planner)

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        self.forget()
        return self.planner.plan_cycle(start_q, mug, slot, on_tray, counter=counter)

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        self.forget()
        return self.planner.plan_for_slot(start_q, slot, counter, on_tray)

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> object:
        raise AssertionError("not asked")


def _same_plan(a: CyclePlan, b: CyclePlan) -> bool:
    if (a.mug_id, a.duration_s, a.energy_j, a.handle_yaw_rad, len(a.steps)) != (
        b.mug_id,
        b.duration_s,
        b.energy_j,
        b.handle_yaw_rad,
        len(b.steps),
    ):
        return False
    for s, t in zip(a.steps, b.steps, strict=True):
        if (s.phase, s.kind, s.aperture_m) != (t.phase, t.kind, t.aperture_m):
            return False
        if (s.trajectory is None) != (t.trajectory is None):
            return False
        if (
            s.trajectory is not None
            and t.trajectory is not None
            and not (
                np.array_equal(s.trajectory.positions, t.trajectory.positions)
                and np.array_equal(s.trajectory.times, t.trajectory.times)
            )
        ):
            return False
    return True


def _same(a: Sequenced, b: Sequenced) -> None:
    assert a.dropped == b.dropped
    assert a.checks == b.checks
    assert [(c.slot, c.planned_for) for c in a.cycles] == [(c.slot, c.planned_for) for c in b.cycles]
    assert all(_same_plan(c.plan, d.plan) for c, d in zip(a.cycles, b.cycles, strict=True))


def test_an_order_check_asked_twice_gives_what_a_planner_that_forgets_gives(planner: CyclePlanner) -> None:
    counter = [FRONT, BEHIND, OTHER]
    afresh = sequence(_Afresh(planner), START_Q, SLOTS, counter)  # type: ignore[arg-type]
    _forgetting(planner)()
    first = sequence(planner, START_Q, SLOTS, counter)
    hits = planner.remembered.hits
    again = sequence(planner, START_Q, SLOTS, counter)
    assert planner.remembered.hits > hits  # the second time is answered from memory
    assert planner.scene._ik.hits > 0
    assert planner.scene._paths.hits > 0
    assert planner.scene._sweeps.hits > 0
    _same(first, afresh)
    _same(again, afresh)
    # A refused cycle asked again: the same text and blockers as worked out afresh.
    blocked = dataclasses.replace(SLOTS[0], mug_id=BEHIND.mug_id)
    refusals = []
    for forget in (True, False, False):
        if forget:
            _forgetting(planner)()
        with pytest.raises(MotionRefused) as e:
            planner.plan_cycle(START_Q, BEHIND, blocked, (), counter=counter)
        refusals.append((str(e.value), e.value.blockers))
    assert refusals[0] == refusals[1] == refusals[2]
    assert "m1" in refusals[0][1]


def test_a_remembered_sweep_finds_the_collision_a_fresh_check_finds(planner: CyclePlanner) -> None:
    arm = planner.arm
    rng = np.random.default_rng(3)
    xy = rng.uniform([0.2, -0.3], [0.5, 0.3], size=(12, 2))
    cylinders = [Cylinder(f"mug m{i}", float(x), float(y), 0.04, 0.0, 0.1) for i, (x, y) in enumerate(xy)]
    remembering = CollisionWorld(arm, cylinders, [], sweeps=Lru(64))
    fresh = CollisionWorld(arm, cylinders, [])
    found = 0
    for _ in range(25):
        q0 = rng.uniform(arm.lower, arm.upper)
        q1 = np.clip(q0 + rng.normal(0.0, 0.3, arm.dof), arm.lower, arm.upper)
        samples = np.linspace(q0, q1, 8)
        ignore = frozenset({f"mug m{rng.integers(12)}"})
        expected = fresh.first_collision(samples, aperture_m=0.08, ignore=ignore)
        for _ in range(2):  # worked out, then remembered
            got = remembering.first_collision(samples, aperture_m=0.08, ignore=ignore)
            assert got == expected
        found += expected is not None
    assert found > 0
    assert remembering.sweeps is not None
    assert remembering.sweeps.hits == 25
