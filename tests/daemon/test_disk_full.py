"""The disk fills mid-job: the daemon publishes ``recording_failed``, ``status`` shows it, the job carries
on to ``done`` and its summary counts the messages the recording lost."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import zenoh

from daemon.app import RunOptions, ServeContext, ServeHooks, serve
from daemon.config import load_config
from daemon.sdnotify import SdNotifier
from daemon.zenoh_session import session_config
from perception import associate
from recorder import HEADER_TOPIC, read_messages, writer
from tests.daemon.conftest import free_port
from tests.fakes.disk import SmallDisk
from tests.fakes.job import make_backend, make_world

ROBOT = "diskfull"


def test_a_disk_full_mid_job_is_published_shown_in_status_and_counted_and_the_job_ends_done(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = SmallDisk(free=10**9)
    monkeypatch.setattr(writer, "open", disk.open, raising=False)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})
    events: list[Mapping[str, object]] = []

    def tap(topic: str, payload: Mapping[str, object]) -> None:
        if topic != "events":
            return
        events.append(payload)
        if payload.get("kind") == "mug_placed":
            disk.free = 0  # full from the first mug on

    def query(verb: str) -> dict[str, Any]:
        with zenoh.open(session_config(listen=[], connect=[endpoint])) as session:
            (reply,) = list(session.get(f"dishbot/{ROBOT}/cmd/{verb}", timeout=5.0))
            assert reply.ok is not None
            result: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
            return result

    async def go() -> tuple[dict[str, Any], dict[str, Any]]:
        stop = asyncio.Event()
        ready: asyncio.Future[ServeContext] = asyncio.get_running_loop().create_future()
        daemon = asyncio.create_task(
            serve(
                config,
                make_backend(make_world(2)),
                associate,
                RunOptions(listen=(endpoint,), connect=(), record_dir=tmp_path),
                notifier=SdNotifier(None),
                stop=stop,
                hooks=ServeHooks(on_publish=(tap,), on_ready=ready.set_result),
            )
        )
        await asyncio.wait_for(ready, 20)
        before = await asyncio.to_thread(query, "status")
        assert (await asyncio.to_thread(query, "start"))["ok"] is True
        for _ in range(500):
            status = await asyncio.to_thread(query, "status")
            if status["state"] == "done" and not status["recording"]["ok"]:
                break
            await asyncio.sleep(0.02)
        stop.set()
        await asyncio.wait_for(daemon, 20)
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
    from cli.commands.client import _readable

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
    assert _readable(reply).splitlines()[-1] == (
        "recording: failed at /rec/r1-job.mcap: [Errno 28] No space left; 7 messages lost"
    )
    assert "recording" not in _readable({**reply, "recording": {"ok": True, "path": "x", "dropped": 0}})
