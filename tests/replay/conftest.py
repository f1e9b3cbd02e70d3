"""Fixtures for the replay tests: small simulated jobs recorded once per test run (by the first pytest-xdist
worker that needs one, for all), and a way to copy a recording with some messages changed (a recording of
what did not happen, to see the replay notice)."""

from __future__ import annotations

import asyncio
import fcntl
import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from daemon.app import ServeContext
from daemon.backend import SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import load_config
from recorder import HEADER_TOPIC, Recorder, read_messages
from recorder.files import is_job_file
from replay.record import record_job
from tests.fakes.daemon import serve_daemon

# Three mugs on the counter: a short job with a flip each (about 70 s of simulated time).
THREE_MUGS = (("m1", "small", 0.22, 0.415), ("m2", "big", 0.064, 0.415), ("m3", "small", -0.092, 0.529))

Change = Callable[[str, dict[str, object]], dict[str, object] | None]


@pytest.fixture(scope="session")
def three_mug_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished job on the kinematic cell: three mugs, seed 0 (read only; for a test whose changed
    recording must leave the job more than one mug to place)."""
    return recorded_once(tmp_path_factory, "kinematic-three-mugs", _kinematic_job(THREE_MUGS))


@pytest.fixture(scope="session")
def two_mug_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished job on the kinematic cell: the first two of the three mugs, seed 0 (read only). Two mugs
    make a job with a second cycle after a first, and a counter mug the arm does not hold (the fault matrix's
    row that moves it); a third mug would only make every replay of it longer."""
    return recorded_once(tmp_path_factory, "kinematic-two-mugs", _kinematic_job(THREE_MUGS[:2]))


@pytest.fixture(scope="session")
def one_mug_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished job on the kinematic cell: the first of the three mugs, seed 0 (read only: a test that
    changes it writes a copy, ``copy_recording``)."""
    return recorded_once(tmp_path_factory, "kinematic-one-mug", _kinematic_job(THREE_MUGS[:1]))


@pytest.fixture(scope="session")
def continued_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``record_continued_job``'s second job (read only: the re-simulation tests of a continued tray, the
    simulated one's and the robot's, each take it)."""
    return recorded_once(tmp_path_factory, "continued", record_continued_job)


def _kinematic_job(mugs: tuple[tuple[str, str, float, float], ...]) -> Callable[[Path], Path]:
    """Records the kinematic cell's job of ``mugs`` (seed 0) in a directory and gives its file."""
    return lambda directory: record_job(directory, world="kinematic", mugs=mugs).path


def recorded_once(
    tmp_path_factory: pytest.TempPathFactory, name: str, record: Callable[[Path], Path]
) -> Path:
    """The job file ``record`` writes in a directory, recorded once for the whole test run: a session
    fixture is built once per pytest-xdist worker, and each worker recorded the same job again (the same
    file, seeded and on simulated time). The workers of a run share their base temporary directory's
    parent: the first to need the job records it there while it holds a lock, the others wait for it and
    take its file (read only, as every test takes these jobs)."""
    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the run's own (a serial run's parent is shared by other runs)
    directory = shared / f"recorded-{name}"
    with open(shared / f"recorded-{name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released as the file closes
        done = directory / "job-path.txt"
        if done.exists():
            return Path(done.read_text(encoding="utf-8"))
        path = record(directory)
        done.write_text(str(path), encoding="utf-8")
        return path


def copy_recording(
    source: Path, target: Path, change: Change, *, clock: Mapping[str, object] | None = None
) -> Path:
    """``source`` written again to ``target`` with the real Recorder, each message's payload passed through
    ``change(topic_suffix, payload)`` (None leaves the message out); ``clock`` replaces the header's."""
    read = read_messages(source)
    messages = list(read.messages)
    header = messages[0].payload
    assert messages[0].topic == HEADER_TOPIC
    with Recorder(target, chunk_size=64 * 1024, lossless=True) as rec:  # a copy drops nothing
        rec.write_header(
            _mapping(header["config"]),
            _mapping(header["scene"]),
            log_time_ns=messages[0].log_time_ns,
            job=_mapping(header.get("job")),
            file=_mapping(header.get("file")),
            clock=clock if clock is not None else _mapping(header.get("clock")),
        )
        for m in messages[1:]:
            suffix = m.topic.split("/", 2)[2]
            payload = change(suffix, dict(m.payload))
            if payload is not None:
                rec.write(m.topic, payload, log_time_ns=m.log_time_ns)
    return target


def _mapping(value: object) -> Mapping[str, object]:
    assert isinstance(value, Mapping)
    return value


def record_continued_job(record_dir: Path) -> Path:
    """A kinematic daemon whose first job (three mugs, started over Zenoh) is stopped after its first
    placement, and a second job, ``start {}``, that goes on with the tray and counter the first left."""

    mugs = [{"id": i, "type": t, "x_m": x, "y_m": y} for i, t, x, y in THREE_MUGS]

    async def run() -> tuple[Path, ...]:
        config = load_config(overrides={"backend": "sim", "sim": {"world": "kinematic", "seed": 0}})
        backend = await open_backend(config, sim=SimOptions(), clock=clock)
        placed = asyncio.Event()
        tasks: list[asyncio.Task[None]] = []

        def on_publish(topic: str, payload: Mapping[str, Any]) -> None:
            if topic == "events" and payload.get("kind") == "mug_placed":
                placed.set()

        async def drive(ctx: ServeContext) -> None:
            assert (await ctx.handle("start", json.dumps({"mugs": mugs}).encode(), False))["ok"]
            await placed.wait()
            await ctx.clock.sleep(4.0)
            assert (await ctx.handle("stop", b"", False))["ok"]
            await ctx.job.finished.wait()
            await ctx.clock.sleep(3.0)
            assert (await ctx.handle("start", b"{}", False))["ok"]
            await ctx.clock.sleep(1.0)
            await ctx.job.finished.wait()
            await ctx.clock.sleep(3.0)
            ctx.stop.set()

        def on_ready(ctx: ServeContext) -> None:
            tasks.append(asyncio.create_task(drive(ctx)))

        result = await serve_daemon(
            config, backend, record_dir, listen=(), on_publish=(on_publish,), on_ready=on_ready
        )
        return result.files

    clock = SimulatedClock()
    jobs = [p for p in clock.run(run()) if is_job_file(p)]
    assert len(jobs) == 2
    return jobs[1]
