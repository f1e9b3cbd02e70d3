"""A real daemon (``serve`` on a simulated clock) on a simulated cell with a fault file injected."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from daemon.app import RunResult, ServeContext
from daemon.backend import Backend, SetupMug, SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import Config, load_config
from daemon.job import StartRequest
from planning.placement import cell_dataset_problem
from recorder import read_messages
from replay.faults import FaultInjector, FaultSpec, parse_faults
from tests.fakes.daemon import serve_daemon
from wire.messages import Payload, plain

ROBOT = "ft"


def robot_config(**overrides: Any) -> Config:
    return load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}, **overrides})


def counter_mugs(config: Config, count: int) -> tuple[SetupMug, ...]:
    """The first ``count`` mugs of dataset 1 on the configured counter."""
    problem = cell_dataset_problem(config.cell, 1)
    return tuple(SetupMug(m.id, m.type, m.x_mm / 1000.0, m.y_mm / 1000.0) for m in problem.mugs[:count])


@dataclass
class FaultRun:
    """What a daemon with faults did: its result, the injector's record, what it published and recorded.
    The recording is read when a test first looks at it: its events and logs alone for ``events`` and
    ``logs`` (what most tests look at), every message for ``recorded``."""

    result: RunResult
    injector: FaultInjector
    backend: Backend  # the cell's backend, as opened (its devices and world for the assertions)
    published: list[tuple[str, dict[str, object]]] = field(default_factory=list)

    @cached_property
    def recorded(self) -> list[tuple[str, dict[str, object]]]:
        """Every message of the run's recordings, in order."""
        return _read(self.result.files)

    @cached_property
    def _events_and_logs(self) -> list[tuple[str, dict[str, object]]]:
        return _read(self.result.files, keep=lambda topic: topic.endswith(("/events", "/log")))

    @property
    def states(self) -> list[str]:
        """The state entered at every transition, in order."""
        return [str(p["dest"]) for p in self.events("transition")]

    def events(self, kind: str | None = None) -> list[dict[str, object]]:
        """The recorded ``events`` (the injector's own included), of ``kind`` when given."""
        events = [p for t, p in self._events_and_logs if t.endswith("/events")]
        return [p for p in events if kind is None or p["kind"] == kind]

    def kinds(self) -> list[str]:
        return [str(p["kind"]) for p in self.events()]

    def event(self, kind: str) -> dict[str, object]:
        found = self.events(kind)
        assert found, f"no {kind} event among {self.kinds()}"
        return found[0]

    def logs(self, event: str) -> list[dict[str, object]]:
        return [p for t, p in self._events_and_logs if t.endswith("/log") and p.get("event") == event]


def _read(
    files: tuple[Path, ...], keep: Callable[[str], bool] | None = None
) -> list[tuple[str, dict[str, object]]]:
    return [(m.topic, m.payload) for path in files for m in read_messages(path, keep=keep)]


def run_with_faults(
    tmp_path: Path,
    text: str | tuple[FaultSpec, ...],
    *,
    world: str = "kinematic",
    mugs: int = 2,
    once: bool = True,
    stop_after_s: float | None = None,
    config: Config | None = None,
    on_ready: Callable[[ServeContext], None] | None = None,
    stop_when: Callable[[list[dict[str, object]]], bool] | None = None,
    polls: int = 20_000,
    prepare: bool = True,
    on_fire: Callable[[FaultSpec], None] | None = None,
) -> FaultRun:
    """Run the daemon with the faults ``text`` lists until its ``once`` job ends, or (``stop_after_s``) that
    many simulated seconds after it is ready, or once ``stop_when`` holds for the events the daemon has
    published so far (checked every half simulated second, at most ``polls`` times: things that happen in
    wall time, as Zenoh links do, take many simulated seconds on an idle daemon at full speed); the
    recording goes under ``tmp_path``."""
    config = config or robot_config()
    faults = parse_faults(text, source="faults.toml", config=config) if isinstance(text, str) else text
    injector = FaultInjector(faults, on_fire=on_fire)
    published: list[tuple[str, dict[str, object]]] = []
    request = StartRequest(mugs=counter_mugs(config, mugs)) if once else None
    clock = SimulatedClock()
    opened: list[Backend] = []

    def tap(topic: str, payload: Mapping[str, object]) -> None:
        published.append((topic, dict(payload)))

    live: list[dict[str, object]] = []

    def ready(ctx: ServeContext) -> None:
        injector.attach(ctx)
        if on_ready is not None:
            on_ready(ctx)
        session = ctx.session
        publish = session.publish

        def published(topic: str, payload: Payload) -> None:  # everything, not only the job's
            if topic == "events":
                live.append(dict(plain(payload)))
            publish(topic, payload)

        session.publish = published  # type: ignore[method-assign]
        if stop_when is not None:

            async def stop_once() -> None:
                for _ in range(polls):
                    if stop_when(live):
                        break
                    await ctx.clock.sleep(0.5)
                ctx.stop.set()

            asyncio.get_running_loop().create_task(stop_once())
        if stop_after_s is not None:

            async def stop_later() -> None:
                await ctx.clock.sleep(stop_after_s)
                ctx.stop.set()

            asyncio.get_running_loop().create_task(stop_later())

    async def run() -> RunResult:
        backend = await open_backend(config, sim=SimOptions(world=world, seed=0), clock=clock)
        opened.append(backend)
        try:
            return await serve_daemon(
                config,
                backend,
                tmp_path / "rec",
                once=request,
                on_publish=(injector.on_publish, tap),
                on_ready=ready,
                prepare=injector.prepare if prepare else None,
            )
        finally:
            injector.close()

    return FaultRun(clock.run(run()), injector, opened[0], published)
