"""A job that stops making progress faults with the reason instead of stalling while the watchdog pings on:
a camera that hangs or sends bad frames (through the real observer), a move that never ends (a state past
its time bound), and a stall the fault itself cannot end (no pings, so systemd restarts the daemon). On a
simulated clock, with the real daemon (``serve``, Zenoh on loopback) and a notify socket standing in for
systemd's."""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import structlog

from daemon.app import ServeContext
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job, StartRequest
from daemon.sdnotify import SdNotifier
from drivers.interfaces import Clock, RGBDFrame
from perception import CameraObserver, associate
from recorder import Recorder, read_messages
from tests.fakes.daemon import serve_daemon
from tests.fakes.devices import ScriptedCamera
from tests.fakes.job import FakeArm, FakeWorld, make_backend, make_world
from wire.messages import plain

Published = list[tuple[str, dict[str, Any]]]


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[socket.socket]:
    """systemd's notify socket, as a datagram socket the daemon sends to."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify.sock"))
    sock.setblocking(False)
    yield sock
    sock.close()


class _TimedNotifier(SdNotifier):
    """The real notifier, to the socket; ``pings`` holds the simulated time of every ``WATCHDOG=1`` the
    socket received (read at once: a datagram socket queues only a few)."""

    def __init__(self, receiver: socket.socket, clock: Clock) -> None:
        super().__init__(receiver.getsockname(), watchdog_usec=2_000_000)  # WatchdogSec=2: ping every 1 s
        self._receiver = receiver
        self._clock = clock
        self.pings: list[float] = []
        self.received: list[str] = []

    def watchdog(self) -> bool:
        sent = super().watchdog()
        while True:
            try:
                message = self._receiver.recv(4096).decode()
            except BlockingIOError:
                return sent
            self.received.append(message)
            if message == "WATCHDOG=1":
                self.pings.append(self._clock.monotonic())


def _events(published: Published, kind: str) -> list[dict[str, Any]]:
    return [p for t, p in published if t == "events" and p["kind"] == kind]


def _camera_job(script: list[str], then: str) -> tuple[Job, Published, ScriptedCamera, float]:
    """A job whose observer is the real one, on a camera scripted to fail; run until it ends."""
    clock = SimulatedClock()
    config = load_config(overrides={"planner": {"method": "bh"}})
    K = config.cell.camera.intrinsics()
    frame = RGBDFrame(
        0.0, np.ones((K.height, K.width), np.float32), K, config.cell.camera.world_from_camera()
    )
    camera = ScriptedCamera(frame, clock, script, then=then)
    backend = make_backend(make_world(2), clock=clock)
    backend.observer = CameraObserver(camera, clock=clock)
    published: Published = []
    job = Job(
        backend, config, lambda topic, payload: published.append((topic, dict(plain(payload)))), associate
    )

    async def go() -> float:
        control = asyncio.create_task(job.run())
        started = clock.monotonic()
        await job.command("start", StartRequest())
        async with clock.timeout(120):
            await job.finished.wait()
        took = clock.monotonic() - started
        await job.shutdown()
        control.cancel()
        return took

    took = clock.run(go())
    return job, published, camera, took


@pytest.mark.parametrize(
    ("fault", "reason", "took_s"),
    [
        ("hang", "camera: no frame within 2.0 s", 6.0),
        ("stale", "camera: frame 600.0 s old", 0.0),
        ("nan", "camera: bad frame (NaN depth)", 0.0),
        ("shape", "camera: bad frame (depth image is 320x240 pixels but the intrinsics say 640x480)", 0.0),
    ],
)
def test_a_failing_camera_faults_the_job_with_the_reason_after_the_retries(
    fault: str, reason: str, took_s: float
) -> None:
    job, published, camera, took = _camera_job([], then=fault)
    assert job.chart.state == "fault"
    assert [e["reason"] for e in _events(published, "fault")] == [reason]
    assert _events(published, "fault")[0]["state"] == "detect"
    assert camera.captures == [fault] * 3
    assert took == pytest.approx(took_s)


class _ArmStuckOnStop(FakeArm):
    """An arm whose stop does not return until ``released`` (a bus that hangs instead of failing)."""

    def __init__(self, world: FakeWorld) -> None:
        super().__init__(world)
        self.released = asyncio.Event()

    async def stop(self) -> None:
        await super().stop()
        await self.released.wait()


def _serve_stuck_move(
    tmp_path: Path, receiver: socket.socket, *, stuck_stop: bool
) -> tuple[Published, _TimedNotifier, dict[str, float]]:
    """A daemon whose job's flip never ends (the turn's move neither finishes nor fails); with
    ``stuck_stop`` the arm's stop hangs too until 15 s after the flip's bound passed. The published
    messages, the notifier and the simulated times of what happened."""
    clock = SimulatedClock()
    world = make_world(2)
    world.hold_in_phase = "flip.turn"
    backend = make_backend(world, clock=clock)
    arm = _ArmStuckOnStop(world)
    if stuck_stop:
        backend.arm = arm
    config = load_config(
        overrides={
            "robot_id": "stall",
            "planner": {"method": "bh"},
            "daemon": {"state_bounds_s": {"flip": 20.0}},
        }
    )
    notifier = _TimedNotifier(receiver, clock)
    published: Published = []
    times: dict[str, float] = {}

    def tap(topic: str, payload: Mapping[str, object]) -> None:
        published.append((topic, dict(plain(payload))))
        if topic == "events" and payload.get("kind") == "transition":
            if payload.get("dest") == "flip.transit":
                times["flip"] = clock.monotonic()
            if payload.get("dest") == "fault":
                times["fault"] = clock.monotonic()

    async def script(ctx: ServeContext) -> None:
        try:
            async with clock.timeout(80.0):
                await ctx.job.command("start", StartRequest())
                if stuck_stop:
                    while ctx.job.overdue() is None:
                        await clock.sleep(0.25)
                    await clock.sleep(15.0)
                    times["released"] = clock.monotonic()
                    arm.released.set()
                await ctx.job.finished.wait()
                await clock.sleep(10.0)
        finally:
            ctx.stop.set()

    tasks: list[asyncio.Task[None]] = []

    def on_ready(ctx: ServeContext) -> None:
        tasks.append(asyncio.get_running_loop().create_task(script(ctx)))

    clock.run(
        serve_daemon(config, backend, tmp_path, notifier=notifier, on_publish=(tap,), on_ready=on_ready)
    )
    assert tasks[0].done()
    tasks[0].result()
    return published, notifier, times


@pytest.mark.slow
def test_a_state_past_its_bound_faults_the_job_once_and_the_watchdog_pings_on_in_fault(
    tmp_path: Path, notify_socket: socket.socket
) -> None:
    published, notifier, times = _serve_stuck_move(tmp_path, notify_socket, stuck_stop=False)
    faults = _events(published, "fault")
    assert [(e["reason"], e["state"]) for e in faults] == [
        ("state flip exceeded its 20 s bound", "flip.turn")
    ]
    assert times["fault"] - times["flip"] == pytest.approx(20.0)
    pings = notifier.pings
    assert max(np.diff(pings)) <= 1.0 + 1e-6  # never a gap: the fault came at once
    assert [t for t in pings if t > times["fault"]] != []  # fault is safe: pinged again


@pytest.mark.slow
def test_a_stall_the_fault_cannot_end_stops_the_watchdog_pings_until_the_job_has_left_the_state(
    tmp_path: Path, notify_socket: socket.socket
) -> None:
    published, notifier, times = _serve_stuck_move(tmp_path, notify_socket, stuck_stop=True)
    bound_passed = times["flip"] + 20.0
    pings = notifier.pings
    silent = [t for t in pings if bound_passed <= t < times["released"]]
    assert silent == []  # 15 s without a ping: systemd (WatchdogSec=2) would have restarted the daemon
    assert [t for t in pings if t < bound_passed][-1] >= bound_passed - 1.0  # pinged up to the bound
    assert times["fault"] == pytest.approx(times["released"])  # the fault ended the stall once it could
    assert [t for t in pings if t > times["fault"]] != []
    assert [e["reason"] for e in _events(published, "fault")] == ["state flip exceeded its 20 s bound"]
    assert "STATUS=stalled: state flip exceeded its 20 s bound" in notifier.received  # systemctl status


class _RaisingLogger:
    """A structlog logger whose every write fails, as a print to a closed pipe does."""

    def __getattr__(self, name: str) -> Any:
        def write(*args: Any, **kwargs: Any) -> None:
            raise BrokenPipeError(32, "Broken pipe")

        return write


@pytest.fixture
def structlog_restored() -> Iterator[None]:
    saved = structlog.get_config()
    try:
        yield
    finally:
        structlog.configure(**saved)


def test_a_state_past_its_bound_faults_even_when_every_log_line_fails(structlog_restored: None) -> None:
    structlog.configure(logger_factory=lambda *args: _RaisingLogger())
    clock = SimulatedClock()
    world = make_world(2)
    world.hold_in_phase = "flip.turn"
    config = load_config(
        overrides={"planner": {"method": "bh"}, "daemon": {"state_bounds_s": {"flip": 20.0}}}
    )
    published: Published = []
    job = Job(
        make_backend(world, clock=clock),
        config,
        lambda topic, payload: published.append((topic, dict(plain(payload)))),
        associate,
    )

    async def go() -> None:
        control = asyncio.create_task(job.run())
        await job.command("start", StartRequest())
        with contextlib.suppress(TimeoutError):
            async with clock.timeout(600.0):
                await job.finished.wait()
        await job.shutdown()
        control.cancel()

    clock.run(go())
    assert job.chart.state == "fault"
    assert [e["reason"] for e in _events(published, "fault")] == ["state flip exceeded its 20 s bound"]


@pytest.mark.slow
def test_a_dead_log_output_changes_nothing_the_job_ends_done_and_the_lost_lines_are_counted(
    tmp_path: Path, structlog_restored: None
) -> None:
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader went away (`| head -n 3` has exited)
    dead = os.fdopen(write_end, "w")
    structlog.configure(logger_factory=structlog.PrintLoggerFactory(dead))
    clock = SimulatedClock()
    config = load_config(overrides={"robot_id": "deadout", "planner": {"method": "bh"}})

    def give_up_after_an_hour(ctx: ServeContext) -> None:  # the bound of this test, not the daemon's
        async def later() -> None:
            await clock.sleep(3600.0)
            ctx.stop.set()

        asyncio.get_running_loop().create_task(later())

    try:
        result = clock.run(
            serve_daemon(
                config,
                make_backend(make_world(2), clock=clock),
                tmp_path,
                once=StartRequest(),
                on_ready=give_up_after_an_hour,
            )
        )
    finally:
        with contextlib.suppress(OSError):
            dead.close()
    assert result.end_state == "done"
    assert result.summary.placed == 2
    assert result.log_lines_lost > 0
    recorded = read_messages(result.recording)
    assert not recorded.truncated
    stopped = [
        m.payload for m in recorded if m.topic.endswith("/log") and m.payload["event"] == "daemon_stopped"
    ]
    assert len(stopped) == 1
    lost_then = stopped[0]["log_lines_lost"]
    assert isinstance(lost_then, int)
    assert 0 < lost_then < result.log_lines_lost  # its own line and later ones are lost too


class _SlowRecorder(Recorder):
    """The recorder on a machine that cannot keep up: a small queue and every message slow to write (wall
    time, as a loaded disk or CPU)."""

    def __init__(self, path: Path, **kwargs: Any) -> None:
        super().__init__(path, **{**kwargs, "queue_size": 64})

    def _handle(self, item: Any) -> bool:
        threading.Event().wait(0.0005)
        return super()._handle(item)


# The slow recorder's flip bound: about 1 300 messages during the stall, twenty times its queue, each
# written 0.5 ms of wall time late (20 s made 5 100 messages a run and most of the test's wall time).
SLOW_RECORDER_FLIP_BOUND_S = 5.0


def _stalled_job_recorded(tmp_path: Path) -> tuple[list[tuple[str, str, float]], int]:
    """A ``once`` job whose flip never ends, on a simulated clock from a fixed start: the events of its
    recording (kind, state, t) and the messages the recording lost."""
    clock = SimulatedClock(wall_start=1_000_000.0)
    world = make_world(2)
    world.hold_in_phase = "flip.turn"
    config = load_config(
        overrides={
            "robot_id": "slowrec",
            "planner": {"method": "bh"},
            "daemon": {"state_bounds_s": {"flip": SLOW_RECORDER_FLIP_BOUND_S}},
        }
    )
    result = clock.run(serve_daemon(config, make_backend(world, clock=clock), tmp_path, once=StartRequest()))
    assert result.end_state == "fault"
    events = [
        (str(m.payload["kind"]), str(m.payload["state"]), float(str(m.payload["t"])))
        for m in read_messages(result.recording)
        if m.topic.endswith("/events")
    ]
    return events, result.summary.recording_dropped


@pytest.mark.slow
def test_on_simulated_time_a_slow_recorder_loses_nothing_and_a_stalled_job_records_the_same_every_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("recorder.files.Recorder", _SlowRecorder)
    runs = [_stalled_job_recorded(tmp_path / f"run{i}") for i in range(2)]
    (events, dropped), (again, dropped_again) = runs
    assert (dropped, dropped_again) == (0, 0)
    assert events == again
    faults = [t for kind, _, t in events if kind == "fault"]
    flip = next(t for _, state, t in events if state.startswith("flip"))
    assert faults == [pytest.approx(flip + SLOW_RECORDER_FLIP_BOUND_S)]  # at the bound, once
