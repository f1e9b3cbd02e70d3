"""The job's use of the planners: a blocked mug's slot goes to a reachable mug of the same type
(``plan_for_slot``), and ``planner.energy_model = "dynamics"`` costs the placement's moves with the arm's
dynamics."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Mapping, Sequence
from typing import Any

from daemon.backend import CyclePlannerSpec, Tray, plan_placement
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job, StartRequest
from perception import associate
from planning.interfaces import CyclePlan, MotionRefused, MugPose, TraySlot
from planning.placement import PlanOptions, dataset_problem
from tests.fakes.job import FakeMotion, FakeWorld, make_backend, make_world


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

    def publish(topic: str, payload: Mapping[str, object]) -> None:
        published.append((topic, dict(payload)))

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


def test_the_dynamics_energy_model_costs_placement_moves_from_the_arm() -> None:
    config = load_config()
    problem = dataset_problem(
        1, counter_region_m=config.cell.counter_region_m, tray_origin_m=config.cell.tray_origin_m
    )
    options = PlanOptions(method="bh", cost="ec", time_limit_s=0.5)
    spec = CyclePlannerSpec(
        config.cell, Tray(config.cell.tray_origin_m, config.cell.tray_size_mm), config.mug_types
    )
    thesis = plan_placement(problem, options, None)
    dynamics = plan_placement(problem, options, spec)
    # The thesis proxy's energy is M·g·Δm per mug (a few joules); the dynamics model's includes the servos'
    # electrical work over whole moves, far more.
    assert thesis.n == dynamics.n > 0
    assert dynamics.E_j > 5 * thesis.E_j
