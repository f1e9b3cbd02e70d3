"""``dishbot bench daemon``: command and publish latency, event-loop jitter, recording throughput and size.

The daemon runs in this process on the simulated kinematic cell on the wall clock, as on the robot,
listening on a free loopback port, with a loading job going (so every topic is published and recorded); a
second Zenoh session, as a remote client would, sends ``status`` queries one after another and subscribes to
``state`` and ``joints``. A probe task on
the daemon's own event loop wakes at 50 Hz and measures how late each wake-up is. That run is made three
times: with the JSON channels only, with the Foxglove channels derived beside them (the default), and with
the live Foxglove server too, a WebSocket client in another process subscribed to every channel. Each run's
job file gives the recording's size per minute of job. Separately, a recorder writes joint samples as fast as
it accepts them, with and without the Foxglove channels derived from them.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import multiprocessing.queues
import os
import socket
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

from cli.commands.output import add_json_flag, emit
from cli.commands.run import association, planning_pool
from daemon.config import load_config
from daemon.errors import UsageError

if TYPE_CHECKING:
    import zenoh

ROBOT = "bench"
PROBE_HZ = 50.0
_CLIENT_SETTLE_S = 1.5  # the client process starts, connects and subscribes before the loop is probed


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "daemon",
        help="command round trip, state publish latency, event-loop jitter at 50 Hz, recording throughput",
        description=(
            "Run the daemon in-process on the simulated cell with a job going and measure over loopback "
            "Zenoh: command round trip (status), state and joints publish-to-receive latency, the event "
            "loop's 50 Hz period jitter while publishing and recording everything, and recording throughput."
        ),
    )
    parser.add_argument(
        "--commands", type=int, default=500, metavar="N", help="status round trips (default 500)"
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=4.0,
        metavar="S",
        help="measuring time for latency and jitter (default 4)",
    )
    parser.add_argument(
        "--messages",
        type=int,
        default=50_000,
        metavar="N",
        help="messages for the recording test (default 50000)",
    )
    add_json_flag(parser)
    parser.set_defaults(handler=_bench)


@dataclass(frozen=True, slots=True)
class _Variant:
    """What one live run records and serves."""

    name: str
    channels: bool  # derive the Foxglove channels into the recording
    live_server: bool  # serve them over WebSocket to a client


VARIANTS: Final = (
    _Variant("JSON channels only", channels=False, live_server=False),
    _Variant("+ Foxglove channels", channels=True, live_server=False),
    _Variant("+ live server, 1 client", channels=True, live_server=True),
)


@dataclass(frozen=True, slots=True)
class _Live:
    round_trip_ms: list[float]
    state_ms: list[float]
    joints_ms: list[float]
    jitter_ms: list[float]
    baseline_jitter_ms: list[float]
    states_seen: int
    job_kb_per_min: float
    job_foxglove_channels: int  # distinct channels with a Foxglove schema in the job files
    live_messages: int  # what the Foxglove client received while the loop was probed


def _bench(args: argparse.Namespace) -> int:
    if not 10 <= args.commands <= 100_000:
        raise UsageError(f"--commands {args.commands}: choose 10-100000")
    if not 1.0 <= args.seconds <= 600:
        raise UsageError(f"--seconds {args.seconds:g}: choose 1-600")
    if not 1000 <= args.messages <= 10_000_000:
        raise UsageError(f"--messages {args.messages}: choose 1000-10000000")
    with tempfile.TemporaryDirectory(prefix="dishbot-bench-") as tmp:
        runs = {
            v.name: asyncio.run(_live(Path(tmp) / f"run{i}", v, args.commands, args.seconds, args.log_level))
            for i, v in enumerate(VARIANTS)
        }
        json_only = _recording_throughput(Path(tmp) / "json.mcap", args.messages, foxglove=False)
        with_foxglove = _recording_throughput(Path(tmp) / "foxglove.mcap", args.messages, foxglove=True)
    main = runs[VARIANTS[1].name]  # the default: what a daemon records
    rows = [
        [
            "command round trip (status)",
            "ms",
            *_percentiles(main.round_trip_ms),
            len(main.round_trip_ms),
            "p99 <= 5",
        ],
        ["state publish -> receive", "ms", *_percentiles(main.state_ms), len(main.state_ms), ""],
        ["joints publish -> receive", "ms", *_percentiles(main.joints_ms), len(main.joints_ms), ""],
        *(
            [
                f"event loop period error at 50 Hz, {name}",
                "ms",
                *_percentiles(run.jitter_ms),
                len(run.jitter_ms),
                "p99 <= 5",
            ]
            for name, run in runs.items()
        ),
        [
            "same, bare loop in another process",
            "ms",
            *_percentiles(main.baseline_jitter_ms),
            len(main.baseline_jitter_ms),
            "machine floor",
        ],
    ]
    live = runs[VARIANTS[2].name]
    emit(
        "dishbot bench daemon",
        ["measure", "unit", "p50", "p99", "max", "samples", "target"],
        rows,
        as_json=args.json,
        extra={
            "recording_messages_per_s": round(json_only[0]),
            "recording_mb_per_s": round(json_only[1], 2),
            "recording_queue_full_waits": json_only[2],
            "recording_messages_per_s_with_foxglove": round(with_foxglove[0]),
            "recording_mb_per_s_with_foxglove": round(with_foxglove[1], 2),
            "job_file_kb_per_min": {name: round(run.job_kb_per_min, 1) for name, run in runs.items()},
            "job_file_foxglove_channels": {name: run.job_foxglove_channels for name, run in runs.items()},
            "live_client_messages_per_s": round(live.live_messages / args.seconds, 1),
            "state_changes_seen": main.states_seen,
            "load_average_1m": round(os.getloadavg()[0], 2),
            "cpus": os.cpu_count(),
        },
    )
    return 0


async def _live(tmp: Path, variant: _Variant, commands: int, seconds: float, log_level: str) -> _Live:
    from daemon.app import RunOptions, serve
    from daemon.backend import SimOptions
    from daemon.cell import open_backend
    from daemon.clock import RealClock
    from daemon.planners import ProcessMotionPlanner
    from daemon.sdnotify import SdNotifier
    from recorder.files import is_job_file

    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    foxglove = ("127.0.0.1", _free_port()) if variant.live_server else None
    config = load_config(
        overrides={
            "robot_id": ROBOT,
            "planner": {"method": "bh"},
            "foxglove": {"channels": variant.channels},
        },
    )
    with planning_pool(log_level) as pool:
        # The wall clock: what is measured is the loop's real-time behaviour, the robot's.
        sim = SimOptions(world="kinematic", dataset=1, seed=0)
        backend = await open_backend(config, sim=sim, clock=RealClock(), executor=pool)
        if isinstance(backend.motion, ProcessMotionPlanner):
            await asyncio.wrap_future(backend.motion.warm_up())
        options = RunOptions(listen=(endpoint,), connect=(), record_dir=tmp, once=None, foxglove=foxglove)
        stop = asyncio.Event()
        ready = asyncio.Event()
        daemon = asyncio.create_task(
            serve(
                config,
                backend,
                association(),
                options,
                notifier=SdNotifier(None),
                on_ready=lambda bus, path: ready.set(),
                stop=stop,
                executor=pool,
            )
        )
        await asyncio.wait_for(ready.wait(), 30)
        probe_errors: list[float] = []
        # Start the helper processes first: spawning them blocks this loop, which must not be measured.
        baseline = _start_bare_probe(seconds + _CLIENT_SETTLE_S)
        viewer = _start_viewer(foxglove, seconds) if foxglove is not None else None
        client = asyncio.create_task(asyncio.to_thread(_client_process, endpoint, commands, seconds))
        await asyncio.sleep(_CLIENT_SETTLE_S)
        probing = asyncio.create_task(_probe(probe_errors))
        try:
            result = await client
            baseline_errors = await asyncio.to_thread(_finish_bare_probe, baseline)
            live_messages = await asyncio.to_thread(_finish_bare_probe, viewer) if viewer else []
        finally:
            probing.cancel()
            stop.set()
            outcome = await daemon
    round_trip, state, joints, states_seen = result
    kb_per_min, foxglove_channels = _job_files([p for p in outcome.files if is_job_file(p)])
    return _Live(
        round_trip,
        state,
        joints,
        probe_errors,
        baseline_errors,
        states_seen,
        kb_per_min,
        foxglove_channels,
        int(sum(live_messages)),
    )


def _job_files(files: list[Path]) -> tuple[float, int]:
    """The job files' size per minute of the time they cover, and how many distinct channels with a
    Foxglove schema (``foxglove.FrameTransforms``...) they hold; each file read once."""
    from recorder import read_messages

    size = sum(p.stat().st_size for p in files)
    reads = [read_messages(p, keep=lambda topic: False) for p in files]
    minutes = sum(((r.end_ns or 0) - (r.start_ns or 0)) / 60e9 for r in reads)
    foxglove = {t for r in reads for t, schema in r.schema_names.items() if schema.startswith("foxglove.")}
    return (size / 1000.0 / minutes if minutes > 0 else float("nan")), len(foxglove)


def _start_viewer(address: tuple[str, int], seconds: float) -> _BareProbe:
    """A Foxglove client in its own process: subscribes to every channel and counts what it receives."""
    context = multiprocessing.get_context("spawn")
    results: multiprocessing.queues.Queue[list[float]] = context.Queue()
    url = f"ws://{address[0]}:{address[1]}"
    process = context.Process(target=_viewer, args=(url, seconds, results), daemon=True)
    process.start()
    return process, results


def _viewer(url: str, seconds: float, results: multiprocessing.queues.Queue[list[float]]) -> None:
    import websockets
    from websockets.typing import Subprotocol

    async def run() -> float:
        received = 0
        protocols = [Subprotocol("foxglove.sdk.v1")]
        async with websockets.connect(url, subprotocols=protocols, max_size=None) as ws:
            subscribed: set[int] = set()
            end = time.monotonic() + _CLIENT_SETTLE_S + seconds
            counting_from = time.monotonic() + _CLIENT_SETTLE_S
            while (left := end - time.monotonic()) > 0:
                try:
                    frame = await asyncio.wait_for(ws.recv(), left)
                except TimeoutError:
                    break
                if isinstance(frame, str):
                    doc = json.loads(frame)
                    new = [c["id"] for c in doc.get("channels", []) if c["id"] not in subscribed]
                    if doc.get("op") == "advertise" and new:
                        subs = [{"id": cid, "channelId": cid} for cid in new]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        subscribed.update(new)
                elif time.monotonic() >= counting_from:
                    received += 1
        return float(received)

    results.put([asyncio.run(run())])


_BareProbe = tuple[multiprocessing.process.BaseProcess, "multiprocessing.queues.Queue[list[float]]"]


def _start_bare_probe(seconds: float) -> _BareProbe:
    """The same 50 Hz probe on an idle event loop in its own process: what the machine's load alone costs."""
    context = multiprocessing.get_context("spawn")
    results: multiprocessing.queues.Queue[list[float]] = context.Queue()
    process = context.Process(target=_bare_probe, args=(seconds, results), daemon=True)
    process.start()
    return process, results


def _finish_bare_probe(probe: _BareProbe) -> list[float]:
    process, results = probe
    try:
        return results.get(timeout=120)
    finally:
        process.join(timeout=10)


def _bare_probe(seconds: float, results: multiprocessing.queues.Queue[list[float]]) -> None:
    async def run() -> list[float]:
        errors: list[float] = []
        task = asyncio.create_task(_probe(errors))
        await asyncio.sleep(seconds)
        task.cancel()
        return errors

    results.put(asyncio.run(run()))


async def _probe(errors: list[float]) -> None:
    """Wake at 50 Hz on the daemon's loop; record how far each period is from 20 ms."""
    period = 1.0 / PROBE_HZ
    last = time.perf_counter()
    next_t = time.monotonic() + period
    while True:
        await asyncio.sleep(max(0.0, next_t - time.monotonic()))
        now = time.perf_counter()
        errors.append(abs((now - last) - period) * 1000.0)
        last = now
        next_t += period


_ClientResult = tuple[list[float], list[float], list[float], int]


def _client_process(endpoint: str, commands: int, seconds: float) -> _ClientResult:
    """Run the client in its own process, as a remote monitor would be: it must not share the daemon's GIL."""
    context = multiprocessing.get_context("spawn")
    results: multiprocessing.queues.Queue[_ClientResult] = context.Queue()
    process = context.Process(target=_client, args=(endpoint, commands, seconds, results), daemon=True)
    process.start()
    try:
        return results.get(timeout=seconds + commands * 0.1 + 60)
    finally:
        process.join(timeout=10)


def _client(
    endpoint: str, commands: int, seconds: float, results: multiprocessing.queues.Queue[_ClientResult]
) -> None:
    """Query ``status`` ``commands`` times and follow state and joints for ``seconds``; put the numbers."""
    import zenoh

    from daemon.zenoh_session import encode, key, session_config
    from wire.messages import Joints, State, decode

    state_ms: list[float] = []
    joints_ms: list[float] = []
    states: set[str] = set()
    lock = threading.Lock()

    def latency(into: list[float], kind: type[State | Joints]) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            received = time.time()
            message = decode(sample.payload.to_bytes(), kind)
            with lock:
                into.append((received - float(message.t)) * 1000.0)
                if isinstance(message, State):
                    states.add(message.state)

        return on_sample

    with zenoh.open(session_config(listen=[], connect=[endpoint])) as session:
        subscribers = [
            session.declare_subscriber(key(ROBOT, "state"), latency(state_ms, State)),
            session.declare_subscriber(key(ROBOT, "joints"), latency(joints_ms, Joints)),
        ]
        time.sleep(_CLIENT_SETTLE_S)  # until the daemon-side probe runs
        _query(session, "start", encode({"dataset": 1}))
        start = time.monotonic()
        round_trip: list[float] = []
        for _ in range(commands):
            t0 = time.perf_counter()
            _query(session, "status")
            round_trip.append((time.perf_counter() - t0) * 1000.0)
        time.sleep(max(0.0, seconds - (time.monotonic() - start)))
        del subscribers
    with lock:
        results.put((round_trip, list(state_ms), list(joints_ms), len(states)))


def _query(session: zenoh.Session, verb: str, payload: bytes = b"") -> None:
    """One command to the daemon with the body ``payload``. The client process imports Zenoh and the wire
    messages only: the daemon's job package would be half a second of imports it never uses, on the cores
    the measured loop shares."""
    from daemon.zenoh_session import key

    replies = list(session.get(key(ROBOT, f"cmd/{verb}"), payload=payload, timeout=5.0))
    if not replies or replies[0].ok is None:
        raise UsageError(f"the daemon did not answer {verb} during the benchmark")


def _recording_throughput(path: Path, messages: int, *, foxglove: bool) -> tuple[float, float, int]:
    """Messages per second and MB/s the recorder takes, from the first write until the file is finished;
    with ``foxglove``, each joint sample also gives its transforms (``/tf``), as in the daemon."""
    from daemon.hardware import scene_view
    from daemon.zenoh_session import key
    from recorder import Recorder

    payload = {
        "t": 0.0,
        "names": ["shoulder_turn", "shoulder_lift", "elbow_lift", "wrist_lift", "wrist_turn"],
        "position_rad": [0.1, -1.2, 1.5, 0.3, -1.5708],
        "velocity_rad_s": [0.0] * 5,
        "load": [0.01] * 5,
    }
    topic = key(ROBOT, "joints")
    deriver = scene_view(load_config()) if foxglove else None
    start = time.perf_counter()
    full = 0
    with Recorder(path, chunk_size=65536, deriver=deriver) as recorder:
        for i in range(messages):
            payload["t"] = i * 0.001
            while not recorder.write(topic, payload, log_time_ns=time.time_ns()):
                full += 1  # the queue is full: wait for the writer, as a sustained rate must
                time.sleep(0.001)
    elapsed = time.perf_counter() - start
    size = path.stat().st_size
    return messages / elapsed, size / elapsed / 1e6, full


def _percentiles(values: list[float]) -> list[float]:
    if not values:
        return [float("nan")] * 3
    ordered = sorted(values)
    p50 = statistics.median(ordered)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return [round(p50, 3), round(p99, 3), round(ordered[-1], 3)]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port
