"""The ``log`` topic keeps an error's reason: a crashed unit's exception as text, the planning worker's
records with their time, in what a remote reader sees and in the recording."""

from __future__ import annotations

import asyncio
import queue
from pathlib import Path
from typing import Any

import pytest

from cli.commands.client import request
from daemon.config import load_config
from perception.interfaces import Observation
from recorder import read_messages
from tests.fakes.daemon import running_daemon
from tests.fakes.job import make_backend, make_world

ROBOT = "logtest"


class _BrokenCamera(RuntimeError):
    """A bug in a unit's collaborator: nothing the job expects."""


@pytest.mark.slow
def test_a_crashed_unit_logs_its_exception_text_and_worker_records_carry_t(tmp_path: Path) -> None:
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})
    backend = make_backend(make_world(2))

    async def broken() -> Observation:
        raise _BrokenCamera("the frame buffer was freed twice")

    backend.observer.observe = broken  # type: ignore[method-assign]
    worker_logs: queue.Queue[Any] = queue.Queue()

    async def scenario() -> tuple[Path, ...]:
        async with running_daemon(config, backend, tmp_path, worker_logs=worker_logs) as d:
            endpoint = d.endpoint
            reply = await asyncio.to_thread(request, endpoint, ROBOT, "start", {}, timeout_s=20.0)
            assert reply is not None
            assert reply["ok"], reply
            # A record as the planning worker's relay puts it: the worker's clock is not the daemon's.
            worker_logs.put({"event": "placement_planned", "level": "info", "process": "planning"})
            for _ in range(500):
                reply = await asyncio.to_thread(request, endpoint, ROBOT, "status", {}, timeout_s=5.0)
                if reply is not None and reply["state"] == "fault":
                    break
                await asyncio.sleep(0.02)
            assert reply is not None
            assert reply["state"] == "fault"
        assert d.result is not None
        return d.result.files

    messages = [m for path in asyncio.run(scenario()) for m in read_messages(path)]
    records = [m.payload for m in messages if m.topic == f"dishbot/{ROBOT}/log"]
    crashed = next(r for r in records if r["event"] == "work_crashed")
    assert "exc_info" not in crashed
    assert crashed["exception"] == (
        "tests.daemon.test_log_topic._BrokenCamera: the frame buffer was freed twice"
    )
    traceback = crashed["traceback"]
    assert isinstance(traceback, str)
    assert traceback.startswith("Traceback (most recent call last):\n")
    assert 'in broken\n    raise _BrokenCamera("the frame buffer was freed twice")' in traceback
    (worker,) = [r for r in records if r.get("process") == "planning"]
    assert worker["event"] == "placement_planned"
    assert isinstance(worker["t"], float)
    first = min(m.log_time_ns for m in messages) / 1e9
    assert first <= worker["t"]  # on the session's clock
