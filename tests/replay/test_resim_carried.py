"""A job that continued an earlier job's tray, recorded on the robot, re-simulated (issue 20, item 3): the
stand-in cell, kinematic and MuJoCo, has the earlier jobs' mugs on its tray where the header's
``job.carried`` says they were placed, not an empty tray.

The robot's recording is the kinematic daemon's continued job (``record_continued_job`` in
``tests/replay/conftest.py``) written again with the header a robot's recording has: the hardware backend,
a scene that says nothing of the mugs, the wall clock. Then nothing but ``job.carried`` says where the
earlier job's mug stands."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import pytest

from daemon.backend import SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from recorder import HEADER_TOPIC, Recorder, read_messages
from replay.engine import ReplayOptions, replay
from replay.resim import Resimulation, cell_truth, continues_earlier_job, first_look_s, world_at
from replay.session import RecordedSession
from tests.replay.test_resim_replay import SLIP, with_faults

# How far a restaged tray mug may stand from its slot: the MuJoCo stand-in lets it settle on the tray.
SETTLED_M = 0.01


def as_the_robot_records_it(source: Path, target: Path) -> Path:
    """``source`` written again with a robot's header: backend hardware, no mugs in the scene, the wall
    clock (every message as it was)."""
    messages = list(read_messages(source).messages)
    assert messages[0].topic == HEADER_TOPIC
    header = messages[0].payload
    config = dict(_mapping(header["config"]))
    config["backend"] = "hardware"
    scene = _mapping(header["scene"])
    with Recorder(target, chunk_size=64 * 1024, lossless=True) as rec:
        rec.write_header(
            config,
            {"backend": "hardware", "tray": scene["tray"]},
            log_time_ns=messages[0].log_time_ns,
            job=_mapping(header["job"]),
            file=_mapping(header["file"]),
            clock={"source": "wall", "wall_start": messages[0].log_time_ns / 1e9},
        )
        for m in messages[1:]:
            rec.write(m.topic, dict(m.payload), log_time_ns=m.log_time_ns)
    return target


def _mapping(value: object) -> Mapping[str, object]:
    assert isinstance(value, Mapping)
    return value


@pytest.fixture(scope="module")
def robot_continued(tmp_path_factory: pytest.TempPathFactory, continued_job: Path) -> RecordedSession:
    directory = tmp_path_factory.mktemp("robot-continued")
    return RecordedSession.load(as_the_robot_records_it(continued_job, directory / "robot-job.mcap"))


def carried_slots(session: RecordedSession) -> dict[str, Mapping[str, object]]:
    carried = _mapping(session.job["carried"])
    slots = carried["on_tray"]
    assert isinstance(slots, list)
    return {str(s["mug_id"]): s for s in slots}


@pytest.mark.slow
def test_the_robot_header_says_only_in_job_carried_where_the_earlier_mug_stands(
    robot_continued: RecordedSession,
) -> None:
    assert robot_continued.backend == "hardware"
    assert not robot_continued.simulated
    assert "mugs" not in robot_continued.scene
    assert continues_earlier_job(robot_continued)
    assert list(carried_slots(robot_continued)) == ["m1"]


@pytest.mark.slow
def test_the_world_the_robot_saw_has_the_carried_mugs_on_the_tray_brim_down(
    robot_continued: RecordedSession,
) -> None:
    slot = carried_slots(robot_continued)["m1"]
    first = first_look_s(robot_continued)
    assert first is not None
    (m1,) = [m for m in world_at(robot_continued, first).on("tray") if m.mug_id == "m1"]
    assert (m1.source, m1.type, m1.upside_down) == ("header", slot["type"], True)
    assert (m1.x_m, m1.y_m) == (slot["x_m"], slot["y_m"])
    assert m1.axis == (0.0, 0.0, -1.0)
    assert m1.bottom_m[2] > 0.05  # on its brim: the bottom a mug's height up


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
def test_the_stand_in_of_a_continued_robot_job_has_the_earlier_mugs_on_its_tray(
    robot_continued: RecordedSession, world: str
) -> None:
    slot = carried_slots(robot_continued)["m1"]
    x0, y0 = slot["x_m"], slot["y_m"]
    assert isinstance(x0, float)
    assert isinstance(y0, float)

    def on_the_slot(truth: Mapping[str, tuple[str, float, float]]) -> list[str]:
        return [k for k, (_, x, y) in truth.items() if math.hypot(x - x0, y - y0) < SETTLED_M]

    async def staged() -> tuple[list[str], dict[str, tuple[str, float, float]]]:
        backend = await open_backend(
            robot_continued.config,
            sim=SimOptions(world=world, transport="inprocess", seed=0),
            clock=clock,
        )
        try:
            before = on_the_slot(cell_truth(backend))  # the stand-in as built: its own counter, no tray
            Resimulation(robot_continued, backend, world=world, from_header=False).job_started()
            return before, cell_truth(backend)
        finally:
            await backend.close()

    clock = SimulatedClock()
    before, truth = clock.run(staged())
    assert before == []
    assert on_the_slot(truth) == ["m1"]
    assert truth["m1"][0] == slot["type"]


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
def test_a_continued_robot_job_replays_to_a_match_and_a_fault_goes_on_beside_the_carried_mug(
    robot_continued: RecordedSession, world: str
) -> None:
    clean = replay(robot_continued, ReplayOptions(resim=world))
    assert clean.first_divergence is None, clean.first_divergence
    report = with_faults(robot_continued, SLIP, resim=world)
    assert report.resim is not None
    assert report.resim.world == world
    assert report.resim.seen is not None
    tray = {m.mug_id: m for m in report.resim.seen.on("tray")}
    assert tray["m1"].source == "header"
    assert report.replayed.final_state == "done"
    placed = [e for e in report.replayed.events if e.kind == "mug_placed"]
    assert placed
    for e in placed:
        x, y = e.detail["x_m"], e.detail["y_m"]
        assert isinstance(x, float)
        assert isinstance(y, float)
        assert math.hypot(x - tray["m1"].x_m, y - tray["m1"].y_m) > 0.05
