"""A mug that fell onto the tray: each look tells the mugs the job placed from a stray (``counter.look``),
the stray keeps its id and stays when a look misses it, the mug the arm was handling gives it its id, and the
strays are obstacles after the placed mugs for the motion planner and in the placement problem."""

from __future__ import annotations

import asyncio
import dataclasses
import math
from pathlib import Path

import pytest

from daemon.config import load_config
from daemon.job import JobContext, Services
from daemon.job.counter import look, tray_obstacles
from daemon.job.plan import problem_of
from daemon.sim_backend import KinematicCounter
from perception import associate
from perception.interfaces import Detection, Observation
from planning.interfaces import MugPose, TraySlot
from planning.placement import PlanOptions, TrayStray
from tests.fakes.job import FakeWorld, make_backend
from tests.replay.faulty import run_with_faults

PLACED = TraySlot("m1", "big", 0.40, 0.0)


class Seen:
    """An observer that sees what the test says, on the counter and on the tray."""

    def __init__(self) -> None:
        self.detections: list[Detection] = []

    async def observe(self) -> Observation:
        return Observation(0.0, tuple(self.detections))


def _services(seen: Seen) -> Services:
    backend = dataclasses.replace(make_backend(FakeWorld(counter={})), observer=seen)
    return Services(backend, load_config(), lambda topic, payload: None, associate, state=lambda: "x")


def _det(type_name: str, x: float, y: float, *, upside_down: bool = False) -> Detection:
    return Detection(type_name, x, y, upside_down, 0.5, 0.9)


def test_a_mug_on_the_tray_away_from_every_slot_is_a_stray_and_stays_one() -> None:
    seen = Seen()
    services = _services(seen)
    assert services.backend.tray.contains(0.55, 0.1)
    assert services.backend.tray.contains(PLACED.x_m, PLACED.y_m)
    ctx = JobContext(planner=PlanOptions(), on_tray=[PLACED], next_id=3)
    counter_mug = _det("small", -0.2, 0.4)
    # the placed mug, seen 12 mm off its slot, is the job's own; the other one on the tray is not
    seen.detections = [counter_mug, _det("big", 0.412, 0.0, upside_down=True), _det("small", 0.55, 0.1)]
    ctx.counter = asyncio.run(look(services, ctx))
    assert list(ctx.counter) == ["m3"]
    assert [(m.mug_id, m.type, m.x_m, m.y_m) for m in ctx.strays] == [("m4", "small", 0.55, 0.1)]
    # seen again 2 cm away: the same stray, where it is now seen
    seen.detections = [counter_mug, _det("small", 0.55, 0.12)]
    ctx.counter = asyncio.run(look(services, ctx))
    assert [(m.mug_id, m.y_m) for m in ctx.strays] == [("m4", 0.12)]
    # a look that misses it: a mug does not leave the tray by itself
    seen.detections = [counter_mug]
    ctx.counter = asyncio.run(look(services, ctx))
    assert [m.mug_id for m in ctx.strays] == ["m4"]
    assert ctx.next_id == 5


def test_the_mug_the_arm_was_handling_gives_its_id_to_the_stray_it_became() -> None:
    seen = Seen()
    services = _services(seen)
    ctx = JobContext(planner=PlanOptions(), on_tray=[PLACED], next_id=1)
    seen.detections = [_det("small", -0.2, 0.4), _det("big", -0.3, 0.4)]
    ctx.counter = asyncio.run(look(services, ctx))
    assert list(ctx.counter) == ["m1", "m2"]
    # m2 was carried and fell on the tray: it is gone from the counter, a new mug lies on the tray
    seen.detections = [_det("small", -0.2, 0.4), _det("big", 0.5, -0.1)]
    ctx.counter = asyncio.run(look(services, ctx, target_id="m2"))
    assert list(ctx.counter) == ["m1"]
    assert [m.mug_id for m in ctx.strays] == ["m2"]
    assert ctx.next_id == 3  # no new name was made


def test_strays_are_obstacles_after_the_placed_mugs_and_in_the_placement_problem() -> None:
    seen = Seen()
    services = _services(seen)
    ctx = JobContext(planner=PlanOptions(), on_tray=[PLACED])
    assert tray_obstacles(ctx) == (PLACED,)  # without strays, what the job always passed
    ctx.strays = [
        MugPose("m7", "small", 0.55, 0.1, 1.0, False, True),
        MugPose("m8", "big", 0.5, -0.1, handle_seen=False),
    ]
    assert tray_obstacles(ctx) == (
        PLACED,
        TraySlot("m7", "small", 0.55, 0.1, handle_yaw_rad=1.0),
        TraySlot("m8", "big", 0.5, -0.1, handle_yaw_rad=None),  # its handle was not seen
    )
    problem = problem_of(services, ctx)
    ox, oy = services.backend.tray.origin_m
    expected = [
        TrayStray("m7", "small", ((0.55 - ox) * 1000.0, (0.1 - oy) * 1000.0), 1.0),
        TrayStray("m8", "big", ((0.5 - ox) * 1000.0, (-0.1 - oy) * 1000.0), None),
    ]
    assert len(problem.strays) == 2
    for got, want in zip(problem.strays, expected, strict=True):
        assert (got.id, got.type, got.handle_yaw_rad) == (want.id, want.type, want.handle_yaw_rad)
        assert all(math.isclose(a, b, abs_tol=1e-9) for a, b in zip(got.brim_mm, want.brim_mm, strict=True))


@pytest.mark.slow
def test_a_mug_that_falls_onto_the_tray_is_left_there_and_the_rest_are_placed_clear_of_it(
    tmp_path: Path,
) -> None:
    """The kinematic cell, three dataset-1 mugs: the second carried mug slips out of the gripper over the
    tray. It is given up where it lies, and the mugs placed after it stand clear of it in the world."""
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "mug_slip"\nat_state = "place.transit"\noccurrence = 2\nafter_s = 1.0\n',
        mugs=3,
    )
    fired = run.injector.fired
    assert [f["kind"] for f in fired] == ["mug_slip"]
    fell = run.event("mug_given_up")
    assert fell["reason"] == "fell on the tray; left there as an obstacle"
    counter = run.backend.counter
    assert isinstance(counter, KinematicCounter)
    world = counter.cell.world.mugs
    (stray,) = [m for m in world.values() if m.where == "tray" and m.mug_id == fired[0]["world_mug"]]
    placed = [m for m in world.values() if m.where == "tray" and m is not stray]
    assert len(placed) == 2
    assert run.result.end_state == "done"
    catalogue = load_config().mug_types
    radius = {m.name: m.diameter_mm / 2000.0 for m in catalogue}
    for m in placed:
        assert math.hypot(m.x_m - stray.x_m, m.y_m - stray.y_m) > radius[m.type] + radius[stray.type]
