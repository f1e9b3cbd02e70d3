"""The planning worker's log records reach the daemon (and so the ``log`` topic) at the daemon's level."""

from __future__ import annotations

import multiprocessing
import threading
from collections.abc import Mapping

import structlog

from cli.commands.run import planning_pool
from daemon.log_relay import LogRelay


def log_in_worker(n: int) -> int:
    """Runs in the planning worker process."""
    log = structlog.get_logger("planning.test")
    log.debug("too_fine", n=n)
    log.info("planned_in_worker", n=n, path=multiprocessing.current_process().name)
    log.warning("worker_warning", n=n)
    return n


def test_worker_records_at_or_above_the_level_are_relayed_with_their_fields() -> None:
    records = multiprocessing.get_context("forkserver").Queue()
    got: list[Mapping[str, object]] = []
    done = threading.Event()

    def deliver(record: Mapping[str, object]) -> None:
        got.append(record)
        if len(got) == 2:
            done.set()

    relay = LogRelay(records, deliver)
    try:
        with planning_pool("info", records) as pool:
            assert pool.submit(log_in_worker, 7).result(timeout=60) == 7
            assert done.wait(timeout=30)
    finally:
        relay.close()
    assert [(r["event"], r["level"], r["n"], r["process"]) for r in got] == [
        ("planned_in_worker", "info", 7, "planning"),
        ("worker_warning", "warning", 7, "planning"),
    ]
    assert isinstance(got[0]["path"], str)
