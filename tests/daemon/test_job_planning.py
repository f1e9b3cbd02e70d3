"""The job's use of the planners: a blocked mug's slot goes to a reachable mug of the same type
(``plan_for_slot``), a slot no motion reaches is planned again only when what blocked it changed, and
``planner.energy_model = "dynamics"`` costs the placement's moves with the arm's dynamics."""

from __future__ import annotations

import asyncio
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import pytest

from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job, JobContext, Services, StartRequest
from daemon.job.cycles import take_next_cycle
from daemon.planners import CyclePlannerSpec, plan_placement
from perception import associate
from perception.interfaces import Detection
from planning.interfaces import CyclePlan, MotionRefused, MugPose, TraySlot
from planning.placement import PlanOptions, TrayMug, cell_dataset_problem
from tests.fakes.job import FakeMotion, FakeWorld, make_backend, make_world
from wire.messages import Payload, plain


class SwappingMotion(FakeMotion):
    """A motion planner test double with ``plan_for_slot``: the first small mug a slot names stands behind
    another small mug (it cannot be reached until that one is gone), like ``CyclePlanner.plan_for_slot``
    it then takes another mug of the slot's type, nearest the arm first."""

    def __init__(self, world: FakeWorld) -> None:
        super().__init__(world)
        self.blocked: dict[str, str] = {}  # true id -> the true id standing in front of it

    def _true(self, mug: MugPose) -> str:
        return min(
            self.w.original,
            key=lambda k: math.hypot(self.w.original[k].x_m - mug.x_m, self.w.original[k].y_m - mug.y_m),
        )

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        named = [m for m in counter if m.mug_id == slot.mug_id]
        others = sorted(
            (m for m in counter if m.type == slot.type and m.mug_id != slot.mug_id),
            key=lambda m: (math.hypot(m.x_m, m.y_m), m.mug_id),
        )
        if slot.type == "small" and not self.blocked and named and others:
            self.blocked[self._true(named[0])] = self._true(others[0])
        for mug in [*named, *others]:
            blocker = self.blocked.get(self._true(mug))
            if blocker is not None and blocker in self.w.counter:
                continue
            return mug, self.plan_cycle(start_q, mug, slot, on_tray, counter=counter)
        raise MotionRefused(f"slot for {slot.mug_id}: no {slot.type} mug can be moved there")


def test_a_blocked_mug_is_swapped_for_a_reachable_one_of_its_type_and_both_are_placed() -> None:
    world = make_world(3)  # small true0 and true2, big true1
    published: list[tuple[str, dict[str, Any]]] = []

    def publish(topic: str, payload: Payload) -> None:
        published.append((topic, dict(plain(payload))))

    backend = make_backend(world, clock=SimulatedClock())
    backend.motion = SwappingMotion(world)
    config = load_config(overrides={"planner": {"method": "bh", "time_limit_s": 0.2}})
    job = Job(backend, config, publish, associate)

    async def go() -> None:
        control = asyncio.create_task(job.run())
        try:
            await job.command("start", StartRequest())
            async with backend.clock.timeout(20):
                await job.finished.wait()
        finally:
            await job.shutdown()
            control.cancel()

    backend.clock.run(go())
    events = [p for t, p in published if t == "events"]
    swaps = [e for e in events if e["kind"] == "mug_swapped"]
    assert len(swaps) == 1
    assert swaps[0]["slot_for"] != swaps[0]["mug_id"]
    assert not [e for e in events if e["kind"] == "mug_given_up"]
    assert (job.chart.state, job.summary.placed, job.summary.failed) == ("done", 3, 0)
    assert sorted(world.placed) == ["true0", "true1", "true2"]
    # the swapped-in mug went first; the blocked one followed once the way was clear
    placed = [e["mug_id"] for e in events if e["kind"] == "mug_placed"]
    assert placed.index(swaps[0]["mug_id"]) < placed.index(swaps[0]["slot_for"])


@pytest.mark.slow
def test_the_dynamics_energy_model_costs_placement_moves_from_the_arm() -> None:
    config = load_config()
    problem = cell_dataset_problem(config.cell, 1)
    options = PlanOptions(method="bh", cost="ec", time_limit_s=0.5)
    spec = CyclePlannerSpec(config.cell, config.cell.tray, config.mug_types)
    thesis = plan_placement(problem, options, None)
    dynamics = plan_placement(problem, options, spec)
    # The thesis proxy's energy is M·g·Δm per mug (a few joules); the dynamics model's includes the servos'
    # electrical work over whole moves, far more.
    assert thesis.n == dynamics.n > 0
    assert dynamics.E_j > 5 * thesis.E_j


# --- deferred slots: planned again only when what blocked them changed --------------------------------------


def _services(world: FakeWorld, published: list[tuple[str, dict[str, Any]]] | None = None) -> Services:
    out = [] if published is None else published
    return Services(
        make_backend(world),
        load_config(),
        lambda topic, payload: out.append((topic, dict(plain(payload)))),
        associate,
        state=lambda: "detect",
    )


def _counter_and_queue(world: FakeWorld, order: Sequence[str]) -> JobContext:
    """A job that planned the world's mugs (ids as in the world) into slots in ``order``."""
    counter = {k: MugPose(k, d.type, d.x_m, d.y_m) for k, d in world.counter.items()}
    queue = [
        (TraySlot(k, counter[k].type, 0.4 + 0.1 * i, 0.0), TrayMug(k, counter[k].type, 100 * i, 0, False))
        for i, k in enumerate(order)
    ]
    return JobContext(planner=PlanOptions(), counter=counter, queue=queue, needs_plan=False)


def _world_big_and_two_small() -> FakeWorld:
    return FakeWorld(
        counter={
            "A": Detection("big", -0.10, 0.30, False, 0.0, 1.0),
            "B": Detection("small", -0.20, 0.32, False, 0.0, 1.0),
            "C": Detection("small", -0.30, 0.34, False, 0.0, 1.0),
        }
    )


def _taken_off(world: FakeWorld, ctx: JobContext, mug_id: str) -> None:
    """The mug went from the counter to the tray."""
    del world.counter[mug_id]
    del ctx.counter[mug_id]


def _calls(services: Services) -> list[str]:
    assert isinstance(services.backend.motion, FakeMotion)
    return services.backend.motion.calls


def test_a_deferred_slot_is_planned_again_only_once_its_blocker_left_the_counter() -> None:
    world = _world_big_and_two_small()
    published: list[tuple[str, dict[str, Any]]] = []
    services = _services(world, published)
    assert isinstance(services.backend.motion, FakeMotion)
    services.backend.motion.blocked_by = {"A": "C"}  # the big mug stands behind small C
    ctx = _counter_and_queue(world, ["A", "B", "C"])

    async def go() -> list[str | None]:
        taken = []
        for mug in ("B", "C", None):
            assert await take_next_cycle(services, ctx)
            taken.append(ctx.current.mug_id if ctx.current else None)
            if mug is not None:
                _taken_off(world, ctx, mug)
        return taken

    assert asyncio.run(go()) == ["B", "C", "A"]
    # A was refused once; while C stood in front of it, planning B's successor did not try A again.
    assert _calls(services) == ["slot:A", "slot:B", "slot:C", "slot:A"]
    refused = [p for t, p in published if t == "events" and p["kind"] == "motion_refused"]
    assert [(r["mug_id"], r["reason"]) for r in refused] == [
        ("A", "A: the gripper would hit the mug in front of it")
    ]


def test_a_deferred_slot_is_planned_again_when_its_blocker_moved_not_when_its_handle_jitters() -> None:
    world = _world_big_and_two_small()
    world.counter["D"] = Detection("small", -0.40, 0.36, False, 0.0, 1.0)
    services = _services(world)
    assert isinstance(services.backend.motion, FakeMotion)
    services.backend.motion.blocked_by = {"A": "C"}
    ctx = _counter_and_queue(world, ["A", "B", "D", "C"])

    async def go() -> None:
        assert await take_next_cycle(services, ctx)  # A refused, B taken
        _taken_off(world, ctx, "B")
        ctx.counter["C"] = replace(ctx.counter["C"], handle_yaw_rad=math.radians(2.0))  # detection noise
        assert await take_next_cycle(services, ctx)  # A not tried, D taken
        _taken_off(world, ctx, "D")
        ctx.counter["C"] = replace(ctx.counter["C"], x_m=-0.33)  # seen 3 cm from where it stood
        assert await take_next_cycle(services, ctx)  # A tried again (still blocked), C taken

    asyncio.run(go())
    assert _calls(services) == ["slot:A", "slot:B", "slot:D", "slot:A", "slot:C"]


def test_a_deferred_slot_is_planned_again_when_a_mug_of_its_type_came() -> None:
    world = _world_big_and_two_small()
    services = _services(world)
    assert isinstance(services.backend.motion, FakeMotion)
    services.backend.motion.blocked_by = {"A": "C"}
    ctx = _counter_and_queue(world, ["A", "B", "C"])

    async def go() -> str:
        assert await take_next_cycle(services, ctx)  # A refused, B taken
        _taken_off(world, ctx, "B")
        world.counter["D"] = Detection("big", -0.05, 0.45, False, 0.0, 1.0)
        ctx.counter["D"] = MugPose("D", "big", -0.05, 0.45)
        assert await take_next_cycle(services, ctx)  # A's slot goes to the new big mug
        assert ctx.current is not None
        return ctx.current.mug_id

    assert asyncio.run(go()) == "D"
    assert _calls(services) == ["slot:A", "slot:B", "slot:A"]


@pytest.mark.slow
def test_mugs_no_motion_reaches_are_left_out_of_the_plan_and_never_tried() -> None:
    world = make_world(5)  # small true0, true2 and true4, big true1 and true3; a big slot is planned first
    published: list[tuple[str, dict[str, Any]]] = []
    backend = make_backend(world, refuse=("true3",))  # big true3 is out of reach ...
    assert isinstance(backend.motion, FakeMotion)
    backend.motion.blocked_by = {"true1": "true3"}  # ... and stands in front of big true1
    config = load_config(overrides={"planner": {"method": "bh", "time_limit_s": 0.2}})
    job = Job(backend, config, lambda t, p: published.append((t, dict(plain(p)))), associate)

    async def go() -> None:
        control = asyncio.create_task(job.run())
        try:
            await job.command("start", StartRequest())
            await asyncio.wait_for(job.finished.wait(), 20)
        finally:
            await job.shutdown()
            control.cancel()

    asyncio.run(go())
    assert (job.chart.state, sorted(world.placed)) == ("done", ["true0", "true2", "true4"])
    events = [p for t, p in published if t == "events"]
    assert not [e for e in events if e["kind"] in ("mug_given_up", "motion_refused")]
    assert [e["dest"] for e in events if e["kind"] == "transition"].count("detect") == 4
    # The plan's check left big true3 out (out of reach) and dropped the slot of big true1 behind it: the
    # job never planned a cycle for either.
    out = [e["mug_id"] for e in events if e["kind"] == "out_of_reach"]
    dropped = [e["mug_id"] for e in events if e["kind"] == "slot_dropped"]
    assert (len(out), len(dropped)) == (1, 1)
    slots = Counter(c for c in backend.motion.calls if c.startswith("slot:"))
    assert [slots[f"slot:{m}"] for m in out + dropped] == [0, 0]
    assert (job.summary.planned, job.summary.placed, job.summary.failed) == (3, 3, 0)
    assert len(job.summary.left_out) == 2


def test_a_mug_given_up_on_the_counter_stays_an_obstacle_for_later_cycles() -> None:
    world = _world_big_and_two_small()
    published: list[tuple[str, dict[str, Any]]] = []
    services = _services(world, published)
    assert isinstance(services.backend.motion, FakeMotion)
    services.backend.motion.blocked_by = {"A": "C"}  # the big mug stands behind small C
    ctx = _counter_and_queue(world, ["A", "B"])
    ctx.given_up.add("C")  # C stays where it is, in front of A, for good

    async def go() -> list[str | None]:
        taken = []
        for mug in ("B", None):
            has_next = await take_next_cycle(services, ctx)
            taken.append(ctx.current.mug_id if has_next and ctx.current else None)
            if mug is not None:
                _taken_off(world, ctx, mug)
        return taken

    # Without C as an obstacle A's cycle would plan straight through it; with it A waits, B goes, and A is
    # given up once nothing else is left (C never moves).
    assert asyncio.run(go()) == ["B", None]
    obstacles = services.backend.motion.obstacles
    assert obstacles
    assert all("C" in o for o in obstacles)  # every cycle planned saw C
    assert "C" not in {c.split(":")[1] for c in _calls(services)}  # and never as a candidate
    given_up = [p["mug_id"] for t, p in published if t == "events" and p["kind"] == "mug_given_up"]
    assert given_up == ["A"]
