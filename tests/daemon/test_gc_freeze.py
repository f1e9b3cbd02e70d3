"""The daemon keeps its start-up heap out of the cyclic collector once per process: a process that serves
again (the tests, bench, replays) leaves each later serve's objects to the collector."""

from __future__ import annotations

import asyncio
import gc
from pathlib import Path

import pytest

from daemon.config import load_config
from tests.fakes.daemon import running_daemon
from tests.fakes.job import make_backend, make_world

pytestmark = pytest.mark.slow


def _serve_once(tmp_path: Path) -> None:
    config = load_config(overrides={"robot_id": "gctest", "planner": {"method": "bh"}})

    async def go() -> None:
        async with running_daemon(config, make_backend(make_world(2)), tmp_path) as d:
            await d.query("status", b"")

    asyncio.run(go())


def test_a_second_serve_in_one_process_does_not_freeze_the_heap_again(tmp_path: Path) -> None:
    gc.unfreeze()
    try:
        _serve_once(tmp_path / "first")
        frozen = gc.get_freeze_count()
        assert frozen > 0  # the first serve froze what it found
        _serve_once(tmp_path / "second")
        # the second serve's objects stay with the collector (frozen ones that die by refcount still go)
        assert gc.get_freeze_count() <= frozen
    finally:
        gc.unfreeze()
