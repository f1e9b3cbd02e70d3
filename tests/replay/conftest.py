"""Fixtures for the replay tests: small simulated jobs recorded once per test run (by the first pytest-xdist
worker that needs one, for all), and a way to copy a recording with some messages changed (a recording of
what did not happen, to see the replay notice)."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import pytest

from recorder import HEADER_TOPIC, Recorder, read_messages
from replay.record import record_job

# Three mugs on the counter: a short job with a flip each (about 70 s of simulated time).
THREE_MUGS = (("m1", "small", 0.22, 0.415), ("m2", "big", 0.064, 0.415), ("m3", "small", -0.092, 0.529))

Change = Callable[[str, dict[str, object]], dict[str, object] | None]


@pytest.fixture(scope="session")
def three_mug_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished job on the kinematic cell: three mugs, seed 0 (read only; for a test whose changed
    recording must leave the job more than one mug to place)."""
    return recorded_once(tmp_path_factory, "kinematic-three-mugs", THREE_MUGS)


@pytest.fixture(scope="session")
def two_mug_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished job on the kinematic cell: the first two of the three mugs, seed 0 (read only). Two mugs
    make a job with a second cycle after a first, and a counter mug the arm does not hold (the fault matrix's
    row that moves it); a third mug would only make every replay of it longer."""
    return recorded_once(tmp_path_factory, "kinematic-two-mugs", THREE_MUGS[:2])


@pytest.fixture(scope="session")
def one_mug_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished job on the kinematic cell: the first of the three mugs, seed 0 (read only: a test that
    changes it writes a copy, ``copy_recording``)."""
    return recorded_once(tmp_path_factory, "kinematic-one-mug", THREE_MUGS[:1])


def recorded_once(
    tmp_path_factory: pytest.TempPathFactory, name: str, mugs: Sequence[tuple[str, str, float, float]]
) -> Path:
    """The kinematic cell's job of ``mugs`` (seed 0), recorded once for the whole test run: a session
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
        path = record_job(directory, world="kinematic", mugs=mugs).path
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
