"""The one harness for daemon-in-the-loop tests: ``serve`` (the job, the telemetry, a Zenoh session on a free
loopback port, the MCAP recording) on the test's own loop, as ``dishbot run`` runs it.

- ``serve_daemon(config, backend, record_dir, once=...)``: run it to its end (a ``once`` job, or until a hook
  sets ``stop``) and return its ``RunResult``; inside ``SimulatedClock.run`` it runs on simulated time.
  ``prepare`` adjusts its ``RunOptions`` first (a fault plan's Zenoh peer: ``FaultInjector.prepare``).
- ``running_daemon(config, backend, record_dir)``: an async context manager yielding a ready ``Daemon``
  (what it publishes, commands over Zenoh from a client session, its ``ServeContext``), stopped when the
  block ends; ``Daemon.result`` then holds what ``serve`` returned.

A daemon starts threads, a Zenoh session and files: a test that starts one is slow, and the harness refuses
to start it for a test not marked ``@pytest.mark.slow`` (``tests.fakes.slow_guard``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from daemon.app import RunOptions, RunResult, ServeContext, ServeHooks, serve
from daemon.backend import Backend
from daemon.config import Config
from daemon.job import StartRequest
from daemon.sdnotify import SdNotifier
from daemon.zenoh_session import ZenohSession, session_config
from perception import associate
from tests.fakes.ports import free_port
from tests.fakes.slow_guard import refuse_unless_slow

Published = list[tuple[str, dict[str, Any]]]
Tap = Callable[[str, Mapping[str, object]], None]

__all__ = ["free_port", "loopback", "running_daemon", "serve_daemon"]


def loopback() -> str:
    """A Zenoh endpoint on a free loopback port."""
    return f"tcp/127.0.0.1:{free_port()}"


async def serve_daemon(
    config: Config,
    backend: Backend,
    record_dir: Path,
    *,
    once: StartRequest | None = None,
    listen: Sequence[str] | None = None,
    connect: Sequence[str] = (),
    notifier: SdNotifier | None = None,
    on_publish: Sequence[Tap] = (),
    on_ready: Callable[[ServeContext], None] | None = None,
    foxglove: tuple[str, int] | None = None,
    worker_logs: Any = None,
    prepare: Callable[[RunOptions], RunOptions] | None = None,
) -> RunResult:
    """``serve`` with the real association (``perception.associate``), no systemd (unless ``notifier``),
    listening on a free loopback port (unless ``listen``), until its ``once`` job ends or a hook sets
    ``stop`` (``ServeContext.stop``); ``prepare`` adjusts the options first."""
    refuse_unless_slow("a daemon")
    options = RunOptions(
        listen=tuple(listen) if listen is not None else (loopback(),),
        connect=tuple(connect),
        record_dir=record_dir,
        once=once,
        foxglove=foxglove,
        worker_logs=worker_logs,
    )
    if prepare is not None:
        options = prepare(options)
    hooks = ServeHooks(on_publish=tuple(on_publish), on_ready=on_ready)
    return await serve(
        config, backend, associate, options, notifier=notifier or SdNotifier(None), hooks=hooks
    )


@dataclass
class Daemon:
    """A daemon ready on the test's loop: what it publishes (in order), its parts, commands over Zenoh."""

    context: ServeContext
    endpoint: str  # where it listens ("" when it listens nowhere)
    record_dir: Path
    published: Published = field(default_factory=list)
    result: RunResult | None = None  # what ``serve`` returned, once stopped
    _task: asyncio.Task[RunResult] | None = None
    _client: zenoh.Session | None = None

    @property
    def session(self) -> ZenohSession:
        return self.context.session

    @property
    def recording(self) -> Path:
        """The file being recorded (the recording directory before the first file opens)."""
        path = self.context.recording.path
        return path if path is not None else self.record_dir

    async def stop(self, *, timeout_s: float = 60.0) -> RunResult:
        """Stop it (as SIGTERM does) and wait until ``serve`` has returned; what it returned."""
        if self.result is None:
            if self._client is not None:  # closing a Zenoh session blocks: off the loop
                await asyncio.to_thread(self._close)
            self.context.stop.set()
            assert self._task is not None
            self.result = await asyncio.wait_for(self._task, timeout_s)
        return self.result

    def events(self, kind: str | None = None) -> list[dict[str, Any]]:
        """What it published on ``events`` (of ``kind``), in order."""
        return [p for t, p in self.published if t == "events" and (kind is None or p["kind"] == kind)]

    async def query(self, verb: str, payload: bytes = b"", *, timeout_s: float = 20.0) -> dict[str, Any]:
        """``verb`` over Zenoh from a client session on its endpoint: the body of its one reply (the reply
        ends the query; the timeout only bounds a daemon that does not answer)."""
        return await asyncio.to_thread(self._query, verb, payload, timeout_s)

    async def command(self, verb: str, body: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """``query`` with a JSON body."""
        return await self.query(verb, json.dumps(dict(body or {})).encode())

    def _query(self, verb: str, payload: bytes, timeout_s: float) -> dict[str, Any]:
        if self._client is None:
            self._client = zenoh.open(session_config(listen=[], connect=[self.endpoint]))
        key = f"dishbot/{self.context.config.robot_id}/cmd/{verb}"
        replies = list(self._client.get(key, payload=payload, timeout=timeout_s))
        assert len(replies) == 1, f"{verb}: {len(replies)} replies"
        ok, err = replies[0].ok, replies[0].err
        assert ok is not None, err.payload.to_string() if err is not None else "no reply"
        result: dict[str, Any] = json.loads(ok.payload.to_bytes())
        return result

    def _close(self) -> None:
        if self._client is not None:
            self._client.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it untyped
            self._client = None


@contextlib.asynccontextmanager
async def running_daemon(
    config: Config,
    backend: Backend,
    record_dir: Path,
    *,
    listen: Sequence[str] | None = None,
    connect: Sequence[str] = (),
    notifier: SdNotifier | None = None,
    on_publish: Sequence[Tap] = (),
    foxglove: tuple[str, int] | None = None,
    worker_logs: Any = None,
    ready_timeout_s: float = 120.0,
    stop_timeout_s: float = 60.0,
) -> AsyncIterator[Daemon]:
    """``serve_daemon`` until the block ends; a ``serve`` that fails before it is ready raises its error.
    The time limits only keep a hang from running on: generous, as a daemon's start on a loaded machine
    (two shared cores at load 20-30) takes many times what it takes on an idle one."""
    published: Published = []
    ready: asyncio.Future[ServeContext] = asyncio.get_running_loop().create_future()
    listen = tuple(listen) if listen is not None else (loopback(),)

    def record(topic: str, payload: Mapping[str, object]) -> None:
        published.append((topic, dict(payload)))

    task = asyncio.create_task(
        serve_daemon(
            config,
            backend,
            record_dir,
            listen=listen,
            connect=connect,
            notifier=notifier,
            on_publish=(record, *on_publish),
            on_ready=ready.set_result,
            foxglove=foxglove,
            worker_logs=worker_logs,
        )
    )
    waits: set[asyncio.Future[Any]] = {task, ready}
    await asyncio.wait(waits, timeout=ready_timeout_s, return_when=asyncio.FIRST_COMPLETED)
    if task.done() and not ready.done():
        task.result()  # raises what stopped it
        raise AssertionError("serve ended before it was ready")
    if not ready.done():
        task.cancel()
        raise AssertionError(f"the daemon was not ready within {ready_timeout_s} s")
    d = Daemon(ready.result(), listen[0] if listen else "", record_dir, published, _task=task)
    try:
        yield d
    finally:
        await d.stop(timeout_s=stop_timeout_s)
