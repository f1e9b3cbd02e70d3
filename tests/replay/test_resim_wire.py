"""The world a recording saw is read through the wire contract: each message as its topic's declared one (a
malformed one is left out), the header's carried slots and an older scene's mugs through their views, and
a ``start`` body as the daemon reads it."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from planning.arm import ArmModel
from replay.resim import continues_earlier_job, world_at
from replay.session import Recorded, RecordedSession
from tests.replay.conftest import copy_recording
from wire.messages import Command, plain

DATA = Path(__file__).parent.parent / "data"
RIG = DATA / "rig-2mugs-job.mcap"


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


@pytest.fixture(scope="module")
def rig() -> RecordedSession:
    return RecordedSession.load(RIG)


def test_a_malformed_look_or_placement_is_left_out_of_the_world(
    rig: RecordedSession, arm: ArmModel, tmp_path: Path
) -> None:
    """A look whose mug has no position, and a placement without its slot, say nothing: the world is what
    it was before them (read leniently, they put a mug at the world's origin)."""
    looks = [m.log_time_ns for m in rig.read.messages if m.topic.endswith("/detections")]
    assert len(looks) >= 2
    seen: list[int] = []
    placements: list[int] = []

    def broken(topic: str, payload: dict[str, object]) -> dict[str, object] | None:
        if topic == "detections":
            seen.append(1)
            mugs = payload["mugs"]
            assert isinstance(mugs, list)
            if len(seen) == 2:  # the second look: its mugs without their x
                return {**payload, "mugs": [{k: v for k, v in d.items() if k != "x_m"} for d in mugs]}
        if topic == "events" and payload.get("kind") == "mug_placed" and not placements:
            placements.append(1)  # the first placement: without its slot
            return {k: v for k, v in payload.items() if k not in ("x_m", "y_m")}
        return payload

    copy = RecordedSession.load(copy_recording(RIG, tmp_path / "broken-job.mcap", broken))
    # The second look is left out: what the counter holds was seen by the first look (or let go of).
    t_look = (looks[1] - rig.start_ns) / 1e9
    got = world_at(copy, t_look + 1e-3, arm=arm).on("counter")
    assert any(m.source == "seen" and m.at_s == t_look for m in world_at(rig, t_look + 1e-3, arm=arm).mugs)
    assert got
    assert all(m.at_s < t_look for m in got)
    assert all(math.hypot(m.x_m, m.y_m) > 0.05 for m in got)
    # The first placement is left out: that mug is not on the tray at (0, 0) but where the gripper let go
    # of it (until the next look, which does not see it on the counter).
    placed = next(e for e in rig.trace.events if e.kind == "mug_placed")
    t = placed.t_s + 0.5
    assert t < t_look
    want = world_at(rig, t, arm=arm)
    got_m1 = next(m for m in world_at(copy, t, arm=arm).mugs if m.mug_id == placed.detail["mug_id"])
    want_m1 = next(m for m in want.mugs if m.mug_id == placed.detail["mug_id"])
    assert (want_m1.where, want_m1.source) == ("tray", "placed")
    assert (got_m1.where, got_m1.source) == ("counter", "released")
    assert math.hypot(got_m1.x_m - want_m1.x_m, got_m1.y_m - want_m1.y_m) < 0.02  # released over its slot
    others = [m for m in world_at(copy, t, arm=arm).mugs if m.mug_id != got_m1.mug_id]
    assert others == [m for m in want.mugs if m.mug_id != got_m1.mug_id]


def test_the_carried_slots_and_an_older_scenes_tray_mugs_are_read_through_their_views(
    rig: RecordedSession, arm: ArmModel
) -> None:
    carried = dataclasses.replace(
        rig,
        job={
            **rig.job,
            "carried": {
                "on_tray": [
                    {"mug_id": "m7", "type": "small", "x_m": 0.3, "y_m": -0.1, "handle_yaw_rad": 1.0},
                    {"mug_id": "m8", "type": "big", "x_m": 0.35, "y_m": -0.1, "rotated": True},
                    {"mug_id": "m9", "type": "big", "x_m": 0.4, "y_m": -0.1, "handle_yaw_rad": None},
                ]
            },
        },
    )
    tray = {m.mug_id: m for m in world_at(carried, 0.0, arm=arm).on("tray")}
    assert {k: (m.x_m, m.y_m, m.handle_yaw_rad, m.source) for k, m in tray.items()} == {
        "m7": (0.3, -0.1, 1.0, "header"),
        "m8": (0.35, -0.1, math.pi / 2.0, "header"),
        "m9": (0.4, -0.1, 0.0, "header"),
    }
    assert all(m.upside_down for m in tray.values())
    older = dataclasses.replace(
        rig,
        scene={
            **rig.scene,
            "mugs": [
                {"id": "m1", "type": "small", "x_m": 0.3, "y_m": -0.1, "where": "tray"},
                {"id": "s5", "type": "big", "x_m": 0.35, "y_m": -0.1, "where": "tray", "upside_down": False},
                {"id": "s6", "type": "big", "x_m": 0.1, "y_m": 0.4, "where": "counter"},
            ],
        },
    )
    tray = {m.mug_id: m for m in world_at(older, 0.0, arm=arm).on("tray")}
    # The job's own m1 was seen on the counter: the earlier one is renamed.
    assert {k: (m.x_m, m.upside_down) for k, m in tray.items()} == {
        "earlier-m1": (0.3, True),
        "s5": (0.35, False),
    }


def _with_start(rig: RecordedSession, body: str, *, after_ns: int = -1) -> RecordedSession:
    command = Command(t=1.0, verb="start", payload=body, reply={"ok": True})
    record = Recorded("input/command", rig.start_ns + after_ns, plain(command), message=command)
    return rig.with_streams({"input/command": (record,)})


@pytest.mark.parametrize(
    ("body", "continues"),
    [
        ("{}", True),
        ("", True),
        ('{"planner": {"seed": 3}}', True),
        ('{"dataset": 1}', False),
        ('{"mugs": [{"id": "m1", "type": "small", "x_m": 0.2, "y_m": 0.4}]}', False),
        ('{"planner": {"speed": 3}}', False),  # refused by the daemon: it started nothing
        ("not json", False),
    ],
)
def test_a_job_continues_an_earlier_one_when_its_start_body_names_neither_dataset_nor_mugs(
    rig: RecordedSession, body: str, continues: bool
) -> None:
    assert continues_earlier_job(_with_start(rig, body)) is continues


def test_a_start_logged_after_the_start_transition_as_on_the_wall_clock_still_continues(
    rig: RecordedSession,
) -> None:
    """The daemon logs a command with its reply, which comes after the transition it caused: on the wall
    clock a few milliseconds after the job's start."""
    assert continues_earlier_job(_with_start(rig, "{}", after_ns=5_000_000))
    assert not continues_earlier_job(_with_start(rig, '{"dataset": 2}', after_ns=5_000_000))
