"""``dishbot bench soak``: many simulated jobs in one daemon, each with a random fault of the matrix.

One daemon (``serve`` on the kinematic cell, simulated time: the real drivers over the device simulators)
runs ``--jobs`` jobs one after the other, each on three mugs of a random dataset, each with one fault drawn
from ``SOAK_FAULTS`` (seeded), which holds every device and world fault kind of a fault file, supply and heat
included. After a job ends the fault is ended (a bus replugged, a sensor speaking again, a servo cooled), a
job that ended in ``fault`` is reset, and the next one starts. Checked: the daemon never crashes (no work unit
raising, no internal error), every job ends in the state docs/faults.md gives for its fault, a fault that did
not fire is reported with its reason (``FaultInjector.outcomes``), every recording file reads back finished,
and the process's memory (RSS) at the start, after the first job and at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import structlog

from cli.commands.output import add_json_flag, emit
from cli.progress import Progress
from daemon.errors import UsageError
from wire.messages import BadMessage, Event, convert, reply_of

log = structlog.get_logger("bench.soak")

# (fault table, the states a job may end in with it): docs/faults.md has the same rows with their reasons.
SOAK_FAULTS: tuple[tuple[Mapping[str, object], frozenset[str]], ...] = (
    ({"kind": "servo_overload", "servo": 3, "at_state": "flip.turn", "after_s": 0.2}, frozenset({"fault"})),
    (
        {"kind": "servo_overload", "servo": 6, "at_state": "side_grasp.close", "after_s": 0.1},
        frozenset({"done"}),
    ),
    ({"kind": "servo_overheat", "servo": 2, "at_state": "side_grasp.lift"}, frozenset({"fault"})),
    ({"kind": "servo_voltage", "servo": 4, "at_state": "flip.transit"}, frozenset({"fault"})),
    ({"kind": "servo_silent", "servo": 4, "at_state": "flip.transit"}, frozenset({"fault"})),
    (
        {"kind": "bus_corrupt", "rate": 0.05, "at_state": "side_grasp.approach", "duration_s": 5.0},
        frozenset({"done"}),
    ),
    ({"kind": "bus_corrupt", "rate": 1.0, "at_state": "place.transit"}, frozenset({"fault"})),
    ({"kind": "bus_unplug", "at_state": "place.descend", "duration_s": 1.0}, frozenset({"fault"})),
    (
        {"kind": "bus_unplug", "device": "fsr", "at_state": "flip.transit", "duration_s": 0.1},
        frozenset({"done"}),
    ),
    ({"kind": "fsr_drop", "at_state": "flip.transit", "duration_s": 0.5}, frozenset({"done"})),
    ({"kind": "fsr_spike", "at_state": "side_grasp.lift"}, frozenset({"done"})),
    ({"kind": "fsr_silent", "at_state": "place.transit"}, frozenset({"fault"})),
    (
        {"kind": "camera_no_frame", "at_state": "detect", "occurrence": 2, "duration_s": 0.5},
        frozenset({"done"}),
    ),
    ({"kind": "camera_no_frame", "at_state": "detect", "occurrence": 2}, frozenset({"fault"})),
    ({"kind": "camera_stale", "at_state": "detect", "occurrence": 2}, frozenset({"fault"})),
    ({"kind": "camera_bad_frame", "at_state": "detect", "occurrence": 2}, frozenset({"fault"})),
    ({"kind": "camera_hang", "at_state": "detect", "occurrence": 2}, frozenset({"fault"})),
    ({"kind": "camera_hang", "at_state": "detect", "occurrence": 2, "duration_s": 3.0}, frozenset({"done"})),
    ({"kind": "mug_slip", "at_state": "flip.transit", "after_s": 0.3}, frozenset({"done"})),
    ({"kind": "mug_moved", "at_state": "side_grasp.lift", "dx_m": 0.03, "dy_m": 0.0}, frozenset({"done"})),
)
_JOB_LIMIT_S = 1800.0  # simulated seconds a job may take before it counts as stuck


@dataclass
class JobRun:
    index: int
    fault: str
    end_state: str
    expected: frozenset[str]
    fired: bool
    reason: str = ""
    # Why the fault did not fire, as the injector reports it (empty: fired, or not reported: a failure).
    unfired_reason: str = ""

    @property
    def as_documented(self) -> bool:
        return self.end_state in self.expected

    @property
    def unfired_unreported(self) -> bool:
        return not self.fired and not self.unfired_reason


@dataclass
class Soak:
    jobs: list[JobRun] = field(default_factory=list)
    crashes: list[str] = field(default_factory=list)
    rss_start_mb: float = 0.0
    rss_samples_mb: list[float] = field(default_factory=list)  # after each job
    rss_end_mb: float = 0.0
    files: tuple[Path, ...] = ()
    unreadable: list[str] = field(default_factory=list)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "soak",
        help="N simulated jobs in one daemon, each with a random fault: crashes, end states, recordings, RSS",
        description=(
            "Run N consecutive jobs in one daemon on the kinematic cell (simulated time; the real drivers "
            "over the device simulators), each on three mugs with one random fault of the matrix "
            "(docs/faults.md; every device and world fault kind, supply and heat included), resetting after "
            "a fault. Prints the jobs per fault, those that did not end in the documented state, faults that "
            "did not fire (and whether the injector said why), crashes, unreadable recordings and the RSS. "
            "Targets: zero crashes, zero unreadable recordings, every job as documented, every unfired fault "
            "reported, RSS growth after the first job under 20 MB over 100 jobs."
        ),
    )
    parser.add_argument("--jobs", type=int, default=100, metavar="N", help="jobs to run (default 100)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the fault draw (default 0)")
    add_json_flag(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if not 1 <= args.jobs <= 10_000:
        raise UsageError(f"--jobs {args.jobs}: choose 1-10000")
    with tempfile.TemporaryDirectory(prefix="dishbot-soak-") as tmp:
        progress = Progress("bench soak", args.jobs, enabled=not args.json)
        result = soak(args.jobs, args.seed, Path(tmp), progress=progress)
    by_kind: dict[str, list[JobRun]] = {}
    for j in result.jobs:
        by_kind.setdefault(j.fault, []).append(j)
    rows = [
        [
            kind,
            len(runs),
            sum(r.fired for r in runs),
            "/".join(sorted(runs[0].expected)),
            ", ".join(f"{s} {n}" for s, n in sorted(_count(r.end_state for r in runs).items())),
            sum(not r.as_documented for r in runs),
        ]
        for kind, runs in sorted(by_kind.items())
    ]
    columns = ["fault", "jobs", "fired", "expected", "ended", "not_as_documented"]
    extra: dict[str, object] = {
        "jobs": len(result.jobs),
        "faults": sum(j.fired for j in result.jobs),
        "crashes": len(result.crashes),
        "not_as_documented": sum(not j.as_documented for j in result.jobs),
        "unfired": sum(not j.fired for j in result.jobs),
        "unfired_unreported": sum(j.unfired_unreported for j in result.jobs),
        "recordings": len(result.files),
        "unreadable_recordings": len(result.unreadable),
        "rss_start_mb": round(result.rss_start_mb, 1),
        "rss_end_mb": round(result.rss_end_mb, 1),
        "rss_growth_mb": round(result.rss_end_mb - result.rss_start_mb, 1),
        "rss_after_first_job_mb": round(result.rss_samples_mb[0], 1) if result.rss_samples_mb else None,
        "rss_growth_after_first_job_mb": round(result.rss_end_mb - result.rss_samples_mb[0], 1)
        if result.rss_samples_mb
        else None,
        "rss_per_decile_mb": [
            round(v, 1) for v in result.rss_samples_mb[:: max(1, len(result.rss_samples_mb) // 10)]
        ],
        "seed": args.seed,
    }
    if result.crashes:
        extra["crash_reasons"] = result.crashes[:10]
    odd = [
        f"job {j.index} ({j.fault}): {j.end_state} {j.reason} {j.unfired_reason}".strip()
        for j in result.jobs
        if not j.as_documented or not j.fired
    ]
    if odd:
        extra["not_as_documented_jobs"] = odd[:20]
    emit("bench soak: jobs with random faults in one daemon", columns, rows, as_json=args.json, extra=extra)
    return 0


def _name(table: Mapping[str, object]) -> str:
    """A soak fault's name for the table: its kind, and what sets it apart from the others of that kind."""
    kind = str(table["kind"])
    if kind == "servo_overload":
        return f"{kind} servo {table['servo']}"
    if kind == "bus_corrupt":
        return f"{kind} {table['rate']}"
    if kind == "bus_unplug":
        return f"{kind} {table.get('device', 'servo')}"
    if "duration_s" in table and kind in ("camera_no_frame", "camera_hang"):
        return f"{kind} {table['duration_s']} s"
    return kind


def _count(items: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for i in items:
        out[i] = out.get(i, 0) + 1
    return out


def rss_mb() -> float:
    """This process's resident set size, from /proc (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def soak(jobs: int, seed: int, record_dir: Path, *, progress: Progress | None = None) -> Soak:
    from daemon.app import RunOptions, ServeContext, ServeHooks, serve
    from daemon.backend import SimOptions
    from daemon.cell import open_backend
    from daemon.clock import SimulatedClock
    from daemon.config import load_config
    from daemon.sdnotify import SdNotifier
    from perception import associate
    from recorder import read_messages
    from replay.engine import fault_text
    from replay.faults import FaultInjector, parse_faults
    from sim.counter import dataset_counter

    config = load_config(overrides={"backend": "sim", "sim": {"world": "kinematic", "seed": seed}})
    rng = random.Random(seed)
    clock = SimulatedClock()
    out = Soak()
    current: list[FaultInjector] = []
    last_fault = [""]

    def on_publish(topic: str, payload: Mapping[str, object]) -> None:
        if current:
            current[0].on_publish(topic, payload)
        event = _event(payload) if topic == "events" else None
        if event is not None and event.kind == "fault":
            reason = event.reason if isinstance(event.reason, str) else ""
            last_fault[0] = reason
            if "internal error" in reason:
                out.crashes.append(reason)

    async def drive(ctx: ServeContext) -> None:
        try:
            out.rss_start_mb = rss_mb()
            t0 = ctx.clock.now()
            for k in range(jobs):
                table, expected = SOAK_FAULTS[rng.randrange(len(SOAK_FAULTS))]
                if progress is not None:
                    progress.step(k + 1, str(table["kind"]), simulated_s=ctx.clock.now() - t0)
                counter = dataset_counter(rng.randint(1, 3), config.cell, config.mug_catalogue())
                mugs = rng.sample(list(counter.mugs), 3)
                injector = FaultInjector(
                    parse_faults(fault_text([table]), source=f"job {k + 1}", config=config)
                )
                injector.attach(ctx)
                current[:] = [injector]
                last_fault[0] = ""
                body = {
                    "mugs": [{"id": m.mug_id, "type": m.spec.name, "x_m": m.x_m, "y_m": m.y_m} for m in mugs]
                }
                reply = await ctx.handle("start", json.dumps(body).encode(), False)
                if reply_of(reply).ok is not True:
                    out.jobs.append(JobRun(k + 1, _name(table), "refused", expected, False, str(reply)))
                    injector.close()
                    continue
                finished = await ctx.clock.wait(asyncio.ensure_future(ctx.job.finished.wait()), _JOB_LIMIT_S)
                state = ctx.job.chart.state if finished else f"stuck in {ctx.job.chart.state}"
                reason = last_fault[0]
                outcome = injector.outcomes()[0]
                out.jobs.append(
                    JobRun(
                        k + 1,
                        _name(table),
                        state,
                        expected,
                        outcome.fired,
                        reason,
                        "" if outcome.fired else str(outcome.reason or ""),
                    )
                )
                injector.close()
                current.clear()
                if ctx.job.chart.state != "idle" and ctx.job.chart.can("stop"):
                    await ctx.handle("stop", b"", False)
                for _ in range(3):
                    if not ctx.job.chart.can("reset"):
                        break
                    await ctx.clock.sleep(1.0)
                    await ctx.handle("reset", b"", False)
                out.rss_samples_mb.append(rss_mb())
                log.info(
                    "soak_job", job=k + 1, fault=table["kind"], end_state=state, rss_mb=out.rss_samples_mb[-1]
                )
            out.rss_end_mb = rss_mb()
        finally:
            ctx.stop.set()

    async def main() -> None:
        backend = await open_backend(config, sim=SimOptions(world="kinematic"), clock=clock)
        tasks: list[asyncio.Task[None]] = []

        def on_ready(ctx: ServeContext) -> None:
            tasks.append(asyncio.create_task(drive(ctx)))

        hooks = ServeHooks(on_publish=(on_publish,), on_ready=on_ready)
        options = RunOptions(listen=(), connect=(), record_dir=record_dir)
        try:
            result = await serve(config, backend, associate, options, notifier=SdNotifier(None), hooks=hooks)
        except Exception as e:  # the daemon itself fell over: that is the crash the soak looks for
            out.crashes.append(f"serve raised {type(e).__name__}: {e}")
            return
        out.files = result.files
        for task in tasks:
            if task.done() and task.exception() is not None:
                out.crashes.append(f"soak driver: {task.exception()!r}")

    clock.run(main())
    for path in out.files:
        try:
            read = read_messages(path)
        except Exception as e:  # RecordingError, or anything else: the file cannot be read
            out.unreadable.append(f"{path.name}: {e}")
            continue
        if read.truncated:
            out.unreadable.append(f"{path.name}: not finished ({read.cut_reason})")
    return out


def _event(payload: Mapping[str, object]) -> Event | None:
    """An ``events`` payload as its declared message (None when it is not one)."""
    try:
        return convert(payload, Event, name="events")
    except BadMessage:
        return None
