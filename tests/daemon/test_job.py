"""The job runner on stand-ins for the world: whole jobs, lost mugs, pause/resume, stop, estop, faults; on a
simulated clock, so the stand-ins' moves take simulated time, not the test's."""

from __future__ import annotations

import asyncio
import random
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import replace
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.backend import Backend, SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import CommandRefused, Job, StartRequest
from daemon.job.counter import reading_order
from description import thesis
from perception import associate
from perception.interfaces import Detection
from planning.interfaces import MotionPlanner
from planning.placement.datasets import cell_dataset_problem
from tests.fakes.job import FakeMotion, FakeWorld, make_backend, make_world
from wire.messages import Payload, plain

Published = list[tuple[str, dict[str, Any]]]


def _job(
    world: FakeWorld, *, refuse: tuple[str, ...] = (), blocked_by: Mapping[str, str] | None = None
) -> tuple[Job, Published]:
    published: Published = []

    def publish(topic: str, payload: Payload) -> None:
        published.append((topic, dict(plain(payload))))

    config = load_config(overrides={"planner": {"method": "bh", "time_limit_s": 0.2}})
    backend = make_backend(world, refuse=refuse, clock=SimulatedClock())
    assert isinstance(backend.motion, FakeMotion)
    backend.motion.blocked_by = dict(blocked_by or {})
    return Job(backend, config, publish, associate), published


def _run(world: FakeWorld, scenario: Callable[[Job], Awaitable[None]], **kw: Any) -> tuple[Job, Published]:
    job, published = _job(world, **kw)

    async def go() -> None:
        control = asyncio.create_task(job.run())
        try:
            async with job.backend.clock.timeout(20):
                await scenario(job)
        finally:
            await job.shutdown()
            control.cancel()

    job.backend.clock.run(go())
    return job, published


def _states(published: Published) -> list[str]:
    return [p["dest"] for t, p in published if t == "events" and p["kind"] == "transition"]


async def _until(job: Job, condition: Callable[[], bool]) -> None:
    """Wait for a transition after which ``condition`` holds."""
    reached = asyncio.Event()
    job.chart.subscribe(lambda _: reached.set() if condition() else None)
    if not condition():
        await reached.wait()


async def _start_and_finish(job: Job) -> None:
    await job.command("start", StartRequest())
    await job.finished.wait()


def test_a_whole_job_places_every_mug_and_ends_done() -> None:
    world = make_world(3)
    job, published = _run(world, _start_and_finish)
    assert job.chart.state == "done"
    assert sorted(world.placed) == ["true0", "true1", "true2"]
    s = job.summary
    assert (s.detected, s.planned, s.placed, s.failed) == (3, 3, 3, 0)
    states = _states(published)
    assert states[:4] == ["detect", "plan", "side_grasp.approach", "side_grasp.close"]
    assert states.count("detect") == 4  # once at the start and once after each mug
    assert states[-2:] == ["detect", "done"]
    plan = next(p for t, p in published if t == "plan")
    assert len(plan["slots"]) == 3
    final = [p for t, p in published if t == "state"][-1]
    assert (final["state"], final["mugs_placed"], final["mugs_total"]) == ("done", 3, 3)
    motion = job.backend.motion
    assert isinstance(motion, FakeMotion)
    # The other counter mugs, for collision checks: the plan's reach probes (alone), its check of each
    # cycle in order, then the job's own cycles.
    assert [len(o) for o in motion.obstacles] == [0, 0, 0, 2, 1, 0, 2, 1, 0]
    # Where each placed mug's handle points (the plan's prediction) goes with it onto the tray.
    placed = [p for t, p in published if t == "events" and p["kind"] == "mug_placed"]
    assert [e["handle_yaw_rad"] for e in placed] == [0.0, 0.1, 0.2]
    assert [s.handle_yaw_rad for s in motion.on_tray_seen[-1]] == [0.0, 0.1]


def test_a_failed_grasp_recovers_the_mug_and_grasps_it_again() -> None:
    world = make_world(2)
    world.fail_grasps = 1
    job, published = _run(world, _start_and_finish)
    states = _states(published)
    i = states.index("recover_lost_mug")
    assert states[i - 1] == "side_grasp.verify"
    assert states[i + 1] == "side_grasp.approach"
    assert (job.summary.placed, job.summary.grasp_failures, job.summary.failed) == (2, 1, 0)


def test_a_mug_that_never_holds_is_left_after_the_configured_attempts_and_the_rest_replanned() -> None:
    world = make_world(3)
    world.always_fail = {"true1"}
    job, published = _run(world, _start_and_finish)
    assert job.chart.state == "done"
    assert job.summary.failed == 1
    assert job.summary.grasp_failures == 3  # grasp.max_attempts
    assert sorted(world.placed) == ["true0", "true2"]
    given_up = [p for t, p in published if t == "events" and p["kind"] == "mug_given_up"]
    assert [g["reason"] for g in given_up] == ["given up after 3 attempts"]
    states = _states(published)
    last = len(states) - 1 - states[::-1].index("recover_lost_mug")
    assert states[last + 1] == "plan"  # the rest is replanned without the mug


def test_a_mug_dropped_while_carrying_is_detected_by_force_and_recovered() -> None:
    world = make_world(1)
    world.drop_in_phase = "place.transit"
    job, published = _run(world, _start_and_finish)
    states = _states(published)
    i = states.index("recover_lost_mug")
    assert states[i - 1] == "place.transit"
    assert "arm.stop" in world.log[world.log.index("follow:place.transit:m1") :]
    assert (job.summary.drops, job.summary.placed) == (1, 1)


def test_a_mug_the_arm_cannot_reach_is_left_out_of_the_plan_and_said_so() -> None:
    world = make_world(3)
    job, published = _run(world, _start_and_finish, refuse=("true2",))
    assert sorted(world.placed) == ["true0", "true1"]
    s = job.summary
    assert (s.planned, s.placed, s.failed, job.chart.state) == (2, 2, 0, "done")
    assert s.left_out == ["out of reach: m3 at (-0.200, 0.320) m: m3 at (-0.200, 0.320) is out of reach"]
    events = [p for t, p in published if t == "events"]
    assert [(e["mug_id"], e["detail"]) for e in events if e["kind"] == "out_of_reach"] == [
        ("m3", "m3 at (-0.200, 0.320) is out of reach")
    ]
    assert not [e for e in events if e["kind"] == "motion_refused"]  # the plan promised only what it can


def test_a_mug_blocked_by_another_counter_mug_is_planned_after_it() -> None:
    world = make_world(3)
    _run(world, _start_and_finish)
    order = list(world.placed)  # the placement's order, undisturbed
    world = make_world(3)
    job, published = _run(world, _start_and_finish, blocked_by={order[0]: order[1]})
    # The plan's check put the blocker first (another mug of the blocked one's type may take its slot first,
    # as the job's plan_for_slot does: the mug-shaped plan's order does that here).
    assert sorted(world.placed) == sorted(order)
    assert world.placed.index(order[1]) < world.placed.index(order[0])
    assert (job.summary.planned, job.summary.placed, job.summary.failed, job.chart.state) == (3, 3, 0, "done")
    kinds = [p["kind"] for t, p in published if t == "events"]
    assert "motion_refused" not in kinds  # the job never tried the blocked one first
    assert "mug_given_up" not in kinds


def test_a_mug_given_up_stays_an_obstacle_when_the_job_replans() -> None:
    world = make_world(3)
    _run(world, _start_and_finish)
    order = list(world.placed)  # the placement's order, undisturbed
    world = make_world(3)
    world.always_fail = {order[0]}  # no grasp of the first mug holds: it is given up and the rest replanned
    job, published = _run(world, _start_and_finish, blocked_by={order[1]: order[0]})
    assert world.placed == [order[2]]  # the mug behind the one given up is not tried: it stays blocked
    s = job.summary
    assert (s.placed, s.failed, job.chart.state) == (1, 1, "done")
    assert len(s.left_out) == 1
    assert s.left_out[0].startswith("slot dropped: ")
    events = [p for t, p in published if t == "events"]
    assert [e["kind"] for e in events if e["kind"] in ("mug_given_up", "slot_dropped")] == [
        "mug_given_up",
        "slot_dropped",
    ]
    assert not [e for e in events if e["kind"] == "motion_refused"]


def test_mugs_blocking_each_other_are_left_out_of_the_plan() -> None:
    world = make_world(3)
    job, published = _run(world, _start_and_finish, blocked_by={"true0": "true1", "true1": "true0"})
    assert world.placed == ["true2"]
    s = job.summary
    assert (s.planned, s.placed, s.failed, job.chart.state) == (1, 1, 0, "done")
    assert len(s.left_out) == 2
    assert all(line.startswith("slot dropped: ") for line in s.left_out)
    dropped = [p["mug_id"] for t, p in published if t == "events" and p["kind"] == "slot_dropped"]
    assert len(dropped) == 2


def test_pause_stops_the_arm_mid_move_and_resume_rejoins_the_move() -> None:
    world = make_world(1)
    world.hold_in_phase = "flip.transit"

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await world.holding_still.wait()
        await job.command("pause")
        assert job.chart.state == "paused"
        assert world.log[-2:] == ["arm.stop", "gripper.stop"]
        moves = len([e for e in world.log if e.startswith("follow")])
        await asyncio.sleep(0.02)
        assert len([e for e in world.log if e.startswith("follow")]) == moves  # nothing moves while paused
        world.q[0] += 0.05  # the arm was pushed off its path while paused
        await job.command("resume")
        assert job.chart.state == "flip.transit"
        await job.finished.wait()

    job, _ = _run(world, scenario)
    motion = job.backend.motion
    assert isinstance(motion, FakeMotion)
    assert motion.bridges == ["flip.transit:m1:bridge"]
    assert (job.chart.state, world.placed) == ("done", ["true0"])


def test_pausing_while_the_gripper_closes_stops_it_and_resume_closes_again() -> None:
    world = make_world(1)
    world.hold_in_close = True

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await world.holding_still.wait()
        await job.command("pause")
        assert world.log[-3:] == ["gripper.stop", "arm.stop", "gripper.stop"]
        await job.command("resume")
        assert job.chart.state == "side_grasp.close"
        await job.finished.wait()

    job, _ = _run(world, scenario)
    assert [e for e in world.log if e.startswith("close:side_grasp")] == ["close:side_grasp.approach:m1"] * 2
    assert (job.chart.state, world.placed) == ("done", ["true0"])


def test_stop_ends_the_job_in_idle_with_the_arm_stopped() -> None:
    world = make_world(2)

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await _until(job, lambda: job.chart.state.startswith("side_grasp"))
        await job.command("stop")
        assert job.chart.state == "idle"
        assert "arm.stop" in world.log
        assert job.finished.is_set()

    _run(world, scenario)


def test_estop_stops_then_relaxes_the_arm_and_only_reset_leaves() -> None:
    world = make_world(2)

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await _until(job, lambda: job.chart.state.startswith("flip"))
        await job.command("estop")
        tail = world.log[-3:]
        assert tail == ["arm.stop", "gripper.stop", "arm.relax"]
        for verb in ("start", "resume", "pause", "stop"):
            with pytest.raises(CommandRefused, match=f"^cannot {verb} in state estop$"):
                await job.command(verb)
        await job.command("reset")
        assert job.chart.state == "idle"

    _run(world, scenario)


def test_a_lost_bus_during_a_move_enters_fault_with_the_reason() -> None:
    world = make_world(1)
    world.bus_lost_in_phase = "side_grasp.lift"

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await job.finished.wait()
        assert job.chart.state == "fault"
        with pytest.raises(CommandRefused, match=r"^cannot start in state fault$"):
            await job.command("start")
        world.bus_lost_in_phase = None
        await job.command("reset")
        assert job.chart.state == "idle"

    _, published = _run(world, scenario)
    faults = [p for t, p in published if t == "events" and p["kind"] == "fault"]
    assert faults[0]["reason"] == "BusLost: bus on /dev/fake is gone"


def test_a_telemetry_fault_while_idle_enters_fault() -> None:
    async def scenario(job: Job) -> None:
        await job.fault("SensorFault: FSR stream stopped on /dev/ttyACM0")
        assert job.chart.state == "fault"

    _, published = _run(make_world(1), scenario)
    assert [p["dest"] for t, p in published if t == "events" and p["kind"] == "transition"] == ["fault"]


def test_commands_not_allowed_in_the_current_state_are_refused_and_change_nothing() -> None:
    async def scenario(job: Job) -> None:
        for verb in ("pause", "resume", "stop", "reset"):
            with pytest.raises(CommandRefused, match=f"^cannot {verb} in state idle$"):
                await job.command(verb)
        assert job.chart.state == "idle"

    _, published = _run(make_world(1), scenario)
    assert published == []


def test_setting_up_a_counter_on_a_backend_without_one_is_refused() -> None:
    async def scenario(job: Job) -> None:
        with pytest.raises(CommandRefused, match=r"^dataset and mugs set up a simulated counter"):
            await job.command("start", StartRequest(dataset=1))
        assert job.chart.state == "idle"

    _run(make_world(1), scenario)


def test_a_mug_added_to_the_counter_during_the_job_is_planned_and_placed() -> None:
    world = make_world(2)

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await _until(job, lambda: job.summary.placed >= 1)
        extra = world.original["true0"]
        world.counter["extra"] = type(extra)("small", -0.35, 0.45, False, 0.0, 1.0)
        world.original["extra"] = world.counter["extra"]
        await job.finished.wait()

    _, published = _run(world, scenario)
    assert sorted(world.placed) == ["extra", "true0", "true1"]
    changed = [p for t, p in published if t == "events" and p["kind"] == "counter_changed"]
    assert [c["came"] for c in changed] == [["m3"]]
    assert len([p for t, p in published if t == "plan"]) == 2


def test_a_new_job_on_the_same_counter_plans_around_the_mugs_already_on_the_tray() -> None:
    world = make_world(3)

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await _until(job, lambda: job.summary.placed >= 1)
        await job.command("stop")
        await job.command("start", StartRequest())
        await job.finished.wait()

    job, published = _run(world, scenario)
    plans = [p for t, p in published if t == "plan"]
    assert len(plans) == 2
    first_slot = plans[0]["slots"][0]
    assert all((s["x_m"], s["y_m"]) != (first_slot["x_m"], first_slot["y_m"]) for s in plans[1]["slots"])
    assert sorted(world.placed) == ["true0", "true1", "true2"]
    assert job.status().mugs_placed == 3


def test_an_empty_counter_ends_the_job_done_with_nothing_to_do() -> None:
    job, published = _run(make_world(0), _start_and_finish)
    assert job.chart.state == "done"
    assert (job.summary.detected, job.summary.planned, job.summary.placed) == (0, 0, 0)
    assert _states(published) == ["detect", "plan", "done"]


def test_starting_on_a_new_dataset_sets_the_simulated_counter_up_and_records_the_scene() -> None:
    config = load_config(overrides={"planner": {"method": "bh"}})
    clock = SimulatedClock()
    published: Published = []

    async def go() -> tuple[Backend, MotionPlanner]:
        backend = await open_backend(config, sim=SimOptions(world="kinematic"), clock=clock)
        first_planner = backend.motion
        job = Job(backend, config, lambda t, p: published.append((t, dict(plain(p)))), associate)
        control = asyncio.create_task(job.run())
        await job.command("start", StartRequest(dataset=4))
        await job.command("stop")
        await job.shutdown()
        control.cancel()
        return backend, first_planner

    backend, first_planner = clock.run(go())
    scene = next(p["scene"] for t, p in published if t == "events" and p["kind"] == "scene_set")
    assert scene["dataset"] == 4
    assert len(scene["mugs"]) == 30  # dataset 4: 20 big and 10 small
    assert scene["tray"]["size_m"] == [0.475, 0.52]  # the full-size tray
    assert backend.tray.size_mm == (475, 520)
    assert backend.motion is not first_planner  # planned for the new tray


def test_after_estop_and_reset_the_next_job_keeps_the_names_of_the_mugs_it_knows() -> None:
    """Issue 23 item 5: the ids went on at m17 on a 12-mug counter after an estop and a reset."""
    world = make_world(4)
    world.hold_in_phase = "place"

    async def scenario(job: Job) -> None:
        await job.command("start", StartRequest())
        await world.holding_still.wait()
        await job.command("estop")
        await job.command("reset")
        await job.command("start", StartRequest())
        await job.finished.wait()

    job, published = _run(world, scenario)
    looks = [[m["id"] for m in p["mugs"]] for t, p in published if t == "detections"]
    first, *later = looks
    assert sorted(first) == ["m1", "m2", "m3", "m4"]
    assert all(set(ids) <= set(first) for ids in later), looks
    placed = [p["mug_id"] for t, p in published if t == "events" and p["kind"] == "mug_placed"]
    assert len(placed) == 3  # the mug in the gripper at the estop is not on the counter any more
    assert set(placed) <= set(first)
    assert job.chart.state == "done"


@settings(max_examples=60, deadline=None)
@given(
    dataset=st.sampled_from(sorted(thesis.DATASETS)),
    noise=st.lists(st.tuples(st.floats(-0.01, 0.01), st.floats(-0.01, 0.01)), min_size=30, max_size=30),
    order=st.randoms(use_true_random=False),
)
def test_new_mugs_are_named_as_the_simulated_dataset_names_them(
    dataset: int, noise: list[tuple[float, float]], order: random.Random
) -> None:
    """Issue 23 item 5: the world called a small mug m1 while the detector called a big one m1. Seen with
    up to 1 cm of noise, in any order, each dataset mug gets the id the dataset gives it."""
    truth = cell_dataset_problem(load_config().cell, dataset).mugs
    seen = [
        Detection(m.type, m.x_mm / 1000 + dx, m.y_mm / 1000 + dy, False, 0.0, 0.9, m.id)  # id: for the check
        for m, (dx, dy) in zip(truth, noise, strict=False)
    ]
    order.shuffle(seen)
    named = reading_order([replace(d, mug_id="") for d in seen])
    by_position = {(d.x_m, d.y_m): d.mug_id for d in seen}
    assert [by_position[(d.x_m, d.y_m)] for d in named] == [f"m{k}" for k in range(1, len(truth) + 1)]
