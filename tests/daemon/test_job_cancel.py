"""Stopping the job's unit of work never swallows the stop of the task that stops it: a control task the
daemon cancels while it waits for a unit to end must end too (it used to take its next item and wait for
ever, and the daemon's shutdown with it, deaf to SIGTERM)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from typing import Any

import pytest

from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job
from daemon.job.runner import cancel_and_wait, wait_cancelled
from perception import associate
from tests.fakes.job import make_backend, make_world


async def _slow_to_stop(stopping: asyncio.Event, release: asyncio.Event) -> None:
    """A unit that, cancelled, takes a while to leave the arm still (as manipulation units do)."""
    try:
        await asyncio.Event().wait()
    except asyncio.CancelledError:
        stopping.set()
        await release.wait()
        raise


@dataclass(frozen=True)
class _Stopping:
    """A unit slow to stop, a task stopping it (the unit has begun to stop) and what lets the unit end."""

    unit: asyncio.Task[None]
    stopper: asyncio.Task[None]
    release: asyncio.Event


async def _stopping(stop: Callable[[asyncio.Task[None]], Coroutine[Any, Any, None]]) -> _Stopping:
    stopping, release = asyncio.Event(), asyncio.Event()
    unit = asyncio.create_task(_slow_to_stop(stopping, release))
    await asyncio.sleep(0)
    stopper = asyncio.create_task(stop(unit))
    await stopping.wait()
    return _Stopping(unit, stopper, release)


async def _cancel_all_then_wait(task: asyncio.Task[None]) -> None:
    """The daemon's shutdown (``serve``'s ``stop_tasks``): every task cancelled, then each waited for."""
    task.cancel()
    await wait_cancelled(task)


STOPS = pytest.mark.parametrize("stop", [cancel_and_wait, _cancel_all_then_wait], ids=["job", "daemon"])


@STOPS
def test_a_caller_cancelled_while_it_waits_for_a_cancelled_task_ends_cancelled(
    stop: Callable[[asyncio.Task[None]], Coroutine[Any, Any, None]],
) -> None:
    async def go() -> None:
        s = await _stopping(stop)
        s.stopper.cancel()  # the daemon stops the control task while it waits for the unit
        s.release.set()
        with pytest.raises(asyncio.CancelledError):
            await s.stopper
        assert s.unit.cancelled()

    asyncio.run(go())


@STOPS
def test_a_caller_not_cancelled_returns_once_the_task_has_ended(
    stop: Callable[[asyncio.Task[None]], Coroutine[Any, Any, None]],
) -> None:
    async def go() -> None:
        s = await _stopping(stop)
        assert not s.stopper.done()  # it waits for the unit to be still
        s.release.set()
        await s.stopper  # no error: the unit's cancellation is what was asked
        assert s.unit.cancelled()

    asyncio.run(go())


def test_the_jobs_control_task_cancelled_while_it_stops_a_unit_ends() -> None:
    config = load_config(overrides={"planner": {"method": "bh", "time_limit_s": 0.2}})
    backend = make_backend(make_world(2), clock=SimulatedClock())
    job = Job(backend, config, lambda _topic, _payload: None, associate)

    def leave_the_state(unit: asyncio.Task[None]) -> Coroutine[Any, Any, None]:
        job._work = unit
        return job._cancel_work()  # as the control task does, leaving a state

    async def go() -> None:
        s = await _stopping(leave_the_state)
        s.stopper.cancel()
        s.release.set()
        with pytest.raises(asyncio.CancelledError):
            await s.stopper

    backend.clock.run(go())
