"""Recording a fresh simulated session to replay: one job on the simulated cell, as ``dishbot run --sim
--once`` runs it, for tests (the pytest plugin) and the replay benchmark.

``transport = "pty"`` (MuJoCo cell only) runs the real Dynamixel and FSR drivers over pseudo-terminals on
the wall clock, exactly the robot's code path down to the serial bytes; it takes as long as the job does.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.app import RunOptions, RunResult, ServeHooks, serve
from daemon.backend import SetupMug, SimOptions
from daemon.cell import open_backend
from daemon.clock import RealClock, SessionClock, SimulatedClock
from daemon.config import Config, load_config, merge_tables
from daemon.errors import UsageError
from daemon.job import StartRequest
from daemon.sdnotify import SdNotifier
from recorder.files import is_job_file


@dataclass(frozen=True, slots=True)
class RecordedJob:
    """A job recorded by ``record_job``: its file and how it ended."""

    path: Path
    result: RunResult


def record_job(
    record_dir: Path,
    *,
    world: str = "kinematic",
    dataset: int = 1,
    seed: int = 0,
    mugs: Sequence[tuple[str, str, float, float]] | None = None,
    transport: str = "inprocess",
    overrides: Mapping[str, Any] | None = None,
    hooks: ServeHooks | None = None,
    clock: SessionClock | None = None,
) -> RecordedJob:
    """Run one simulated job (``dataset``'s mugs, or ``mugs`` as ``(id, type, x_m, y_m)``) with detection
    noise seed ``seed`` and record it in ``record_dir``; blocking. ``overrides`` are config tables merged
    over the defaults (``load_config``)."""
    base: dict[str, Any] = {"backend": "sim", "sim": {"world": world, "seed": seed, "transport": transport}}
    config = load_config(overrides=merge_tables(base, overrides or {}))
    if clock is None:
        clock = RealClock() if transport == "pty" else SimulatedClock()
    request = StartRequest(mugs=tuple(SetupMug(*m) for m in mugs) if mugs is not None else None)
    result = clock.run(_run(config, clock, record_dir, dataset, request, hooks))
    jobs = [p for p in result.files if is_job_file(p)]
    if not jobs:
        raise UsageError(f"no job was recorded in {record_dir}")
    return RecordedJob(jobs[-1], result)


async def _run(
    config: Config,
    clock: SessionClock,
    record_dir: Path,
    dataset: int,
    request: StartRequest,
    hooks: ServeHooks | None,
) -> RunResult:
    backend = await open_backend(config, sim=SimOptions(dataset=dataset), clock=clock)
    from perception import associate

    options = RunOptions(listen=(), connect=(), record_dir=record_dir, once=request)
    return await serve(config, backend, associate, options, notifier=SdNotifier(None), hooks=hooks)
