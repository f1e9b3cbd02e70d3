"""A job that stops making progress faults with the reason instead of stalling while the watchdog pings on:
a camera that hangs or sends bad frames (through the real observer), a move that never ends (a state past
its time bound), and a stall the fault itself cannot end (no pings, so systemd restarts the daemon). On a
simulated clock, with the real daemon (``serve``, Zenoh on loopback) and a notify socket standing in for
systemd's."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.app import RunOptions, ServeContext, ServeHooks, serve
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job, StartRequest
from daemon.sdnotify import SdNotifier
from drivers.interfaces import Clock, RGBDFrame
from perception import CameraObserver, associate
from tests.daemon.conftest import free_port
from tests.fakes.devices import ScriptedCamera
from tests.fakes.job import FakeArm, FakeWorld, make_backend, make_world

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
    job = Job(backend, config, lambda topic, payload: published.append((topic, dict(payload))), associate)

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
        published.append((topic, dict(payload)))
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

    options = RunOptions(listen=(f"tcp/127.0.0.1:{free_port()}",), connect=(), record_dir=tmp_path)
    clock.run(
        serve(
            config,
            backend,
            associate,
            options,
            notifier=notifier,
            hooks=ServeHooks(on_publish=(tap,), on_ready=on_ready),
        )
    )
    assert tasks[0].done()
    tasks[0].result()
    return published, notifier, times


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
