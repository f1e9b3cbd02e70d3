"""The disk fills mid-job: the daemon publishes ``recording_failed``, ``status`` shows it, the job carries
on to ``done`` and its summary counts the messages the recording lost; once there is room again the
recording goes on (``recording_restored``) and only what came while the disk was full is lost."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

from daemon.app import ServeContext
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import StartRequest
from recorder import HEADER_TOPIC, read_messages, writer
from tests.fakes.daemon import running_daemon, serve_daemon
from tests.fakes.disk import SmallDisk
from tests.fakes.job import make_backend, make_world

ROBOT = "diskfull"
FULL_FOR_S = 0.02  # the fake cell's whole job takes about a tenth of a simulated second


@pytest.mark.slow
def test_a_disk_full_mid_job_is_published_shown_in_status_and_counted_and_the_job_ends_done(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = SmallDisk(free=10**9)
    monkeypatch.setattr(writer, "open", disk.open, raising=False)
    # Small chunks: the recorder writes (and finds the disk full) within the fake cell's short job, however
    # much each message of the job weighs (a chunk of the default 64 KiB may not fill between two mugs).
    config = load_config(
        overrides={"robot_id": ROBOT, "planner": {"method": "bh"}, "recording": {"chunk_size_bytes": 4096}}
    )
    events: list[Mapping[str, object]] = []

    def tap(topic: str, payload: Mapping[str, object]) -> None:
        if topic != "events":
            return
        events.append(payload)
        if payload.get("kind") == "mug_placed":
            disk.free = 0  # full from the first mug on

    async def go() -> tuple[dict[str, Any], dict[str, Any]]:
        async with running_daemon(config, make_backend(make_world(2)), tmp_path, on_publish=(tap,)) as d:
            before = await d.query("status")
            assert (await d.query("start"))["ok"] is True
            for _ in range(500):
                status = await d.query("status")
                if status["state"] == "done" and not status["recording"]["ok"]:
                    break
                await asyncio.sleep(0.02)
        return before, status

    before, status = asyncio.run(go())
    assert before["recording"]["ok"] is True
    assert before["recording"]["dropped"] == 0
    assert status["state"] == "done"
    assert status["summary"]["placed"] == 2
    recording = status["recording"]
    assert recording["ok"] is False
    assert recording["error"] == "[Errno 28] No space left on device"
    assert recording["path"].endswith("-job.mcap")
    assert recording["dropped"] > 0
    assert 0 < status["summary"]["recording_dropped"] <= recording["dropped"]
    failed = [e for e in events if e["kind"] == "recording_failed"]
    assert len(failed) == 1
    assert failed[0]["error"] == "[Errno 28] No space left on device"
    assert failed[0]["path"] == recording["path"]
    kinds = [e["kind"] for e in events]
    assert kinds.index("recording_failed") < kinds.index("mug_placed", kinds.index("mug_placed") + 1)
    assert "fault" not in kinds
    cut = read_messages(Path(recording["path"]))  # readable up to where the disk filled
    assert cut.truncated
    assert next(m.topic for m in cut) == HEADER_TOPIC
    print(f"dropped {recording['dropped']}, of the job {status['summary']['recording_dropped']}")


def test_the_status_verb_prints_a_failed_recording() -> None:
    from cli.commands.client import _readable, reply_of

    reply = {
        "robot_id": "r1",
        "state": "place.descend",
        "allowed": ["status", "pause"],
        "recording": {
            "ok": False,
            "path": "/rec/r1-job.mcap",
            "error": "[Errno 28] No space left",
            "dropped": 7,
        },
    }
    assert _readable(reply_of(reply)).splitlines()[-1] == (
        "recording: failed at /rec/r1-job.mcap: [Errno 28] No space left; 7 messages lost"
    )
    working = {**reply, "recording": {"ok": True, "path": "x", "dropped": 0}}
    assert "recording" not in _readable(reply_of(working))


@pytest.mark.slow
def test_a_disk_full_for_a_while_mid_job_costs_only_that_while_and_the_job_file_goes_on_to_done(
    tmp_path: Path,
) -> None:
    clock = SimulatedClock(wall_start=2_000_000.0)
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})
    events: list[Mapping[str, object]] = []
    full: list[int] = []  # [from, until) in log-time nanoseconds
    contexts: list[ServeContext] = []

    def now_ns() -> int:
        return round(clock.now() * 1e9)

    def tap(topic: str, payload: Mapping[str, object]) -> None:
        if topic != "events":
            return
        events.append(payload)
        if payload.get("kind") == "transition" and payload.get("dest") == "side_grasp.approach" and not full:
            disk = contexts[0].recording.disk
            full.append(now_ns())
            disk.fill(full[0])

            def freed() -> None:
                full.append(now_ns())
                disk.free(full[1])

            asyncio.get_running_loop().call_later(FULL_FOR_S, freed)

    result = clock.run(
        serve_daemon(
            config,
            make_backend(make_world(2), clock=clock),
            tmp_path,
            once=StartRequest(),
            on_publish=(tap,),
            on_ready=contexts.append,
        )
    )
    assert result.end_state == "done"
    assert full[1] - full[0] == round(FULL_FOR_S * 1e9)
    kinds = [e["kind"] for e in events]
    assert kinds.count("recording_failed") == kinds.count("recording_restored") == 1
    assert kinds.index("recording_failed") < kinds.index("recording_restored")
    assert result.files == (result.recording,)  # the same file went on: it was intact
    recorded = read_messages(result.recording)
    assert not recorded.truncated
    times = [m.log_time_ns for m in recorded]
    assert [t for t in times if full[0] < t < full[1]] == []  # what came while full is lost, only that
    assert [t for t in times if t >= full[1]] != []
    lost = result.summary.recording_dropped
    assert lost > 0
    restored = next(e for e in events if e["kind"] == "recording_restored")
    assert restored["path"] == str(result.recording)
    done = [m for m in recorded if m.topic.endswith("/events") and m.payload.get("dest") == "done"]
    assert len(done) == 1  # the job's end is in its file
    print(f"{FULL_FOR_S} s of full disk lost {lost} messages")
