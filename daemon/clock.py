"""The daemon's clocks: the wall clock on the robot, simulated time in the simulated cell.

Everything that reads or waits on time is constructed with one ``drivers.interfaces.Clock`` and goes
through it. ``RealClock`` is the wall clock and asyncio's ordinary event loop. ``SimulatedClock`` runs an
event loop whose ``time()`` is the simulation's: time stands still while anything is happening and jumps to
the next timer as soon as every task is waiting on the clock, so a simulated job runs as fast as the machine
allows (``speed=None``) or at a chosen factor of real time (``speed=1.0`` for a person watching).

Determinism (the same run twice gives the same states and events) rests on three rules the simulated loop
enforces:

- Time advances only when the loop has nothing ready to run and no executor work is in flight: a bus
  transaction on its thread, a detection in the thread pool or a plan in the planning process all take no
  simulated time, however long they take on this machine.
- Executor results are handed back only when the loop is idle and all work in flight has finished, in the
  order it was submitted, so the interleaving of tasks does not depend on which thread finished first.
- The simulated world is stepped by the clock (``add_stepper``) as time advances, on the loop's thread, so
  every reader sees the world exactly at the clock's time.
- Executor work may take simulated time on purpose (``SimulatedClock.sleep_off_loop``: a replay serving a
  computation that took that long on the robot): while it waits, it counts as waiting on the clock, not as
  work in flight, and when its time comes it goes on before anything else runs at that time.
- Time does not advance while anything the daemon hands work to is behind (``add_backlog``: the recorder's
  queue). On the wall clock a recorder that cannot keep up drops messages rather than stall the robot; in
  simulation time simply waits for it, so nothing is dropped and a run does not depend on this machine's load.

Only external input (a command from another process, a signal) arrives at a moment that depends on the wall
clock. docs/architecture.md ("One clock") says why this design rather than a clock object with its own
scheduler.

This module and the benchmarks are the only places that read the wall clock (``tests/test_one_clock.py``
checks it); ``wall_seconds`` is for measuring how long work took on this machine, never for behaviour.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import math
import selectors
import threading
import time
from collections.abc import Callable, Coroutine
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Final, Protocol, TypeVar, TypeVarTuple

from drivers.interfaces import Clock

T = TypeVar("T")
Ts = TypeVarTuple("Ts")

# Behind the wall clock by more than this at a speed factor (the machine could not keep up, or time stood
# still for a computation): start pacing afresh from here instead of racing to catch up.
_BEHIND_S: Final = 0.25
# How often a loop waiting for executor work looks for input from outside (a signal, a command).
_EXTERNAL_POLL_S: Final = 0.02
SPEED_RANGE: Final = (0.1, 1000.0)


def wall_seconds() -> float:
    """A reading of this machine's performance counter: for measuring how long work took (the ``--once``
    summary, the benchmarks), never for the robot's behaviour."""
    return time.perf_counter()


async def every_wall_period(period_s: float, action: Callable[[], None]) -> None:
    """Run ``action`` on this task's loop every ``period_s`` of wall time, without drifting, until cancelled.

    For what is watched on the wall clock whatever clock the session runs on: systemd's watchdog. Simulated
    time stands still while a plan is being computed (seconds on the full tray), so pings on it would stop
    for that long. A thread keeps the wall clock's schedule and hands each call to the loop, which runs it:
    a loop that is stuck still runs none."""
    loop = asyncio.get_running_loop()
    stop = threading.Event()

    def schedule() -> None:
        next_t = time.monotonic() + period_s
        while not stop.wait(max(0.0, next_t - time.monotonic())):
            next_t += period_s
            try:
                loop.call_soon_threadsafe(action)
            except RuntimeError:  # the loop is closed: the daemon is gone
                return

    thread = threading.Thread(target=schedule, name="wall-period", daemon=True)
    action()
    thread.start()
    try:
        await asyncio.Event().wait()  # until cancelled
    finally:
        stop.set()


def parse_speed(text: str) -> float | None:
    """``--speed``: ``max`` (None: as fast as the machine allows) or simulated seconds per wall second in
    ``SPEED_RANGE``; ``ValueError`` saying what is allowed otherwise."""
    if text.strip().lower() == "max":
        return None
    lo, hi = SPEED_RANGE
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ValueError(f"{text}: choose max or {lo:g}-{hi:g} simulated seconds per second")
    return value


def describe_speed(speed: float | None) -> str:
    return "max" if speed is None else f"{speed:g}"


# Whether a helper thread has caught up with the work handed to it, waiting up to that many wall seconds.
CaughtUp = Callable[[float], bool]


class SessionClock(Clock, Protocol):
    """The clock a daemon session runs on: a ``Clock`` that also runs the session's event loop and says
    what it is for the recording's header."""

    def add_backlog(self, caught_up: CaughtUp) -> Callable[[], None]:
        """Hold time back while ``caught_up`` says a helper is behind (simulated time only: the wall clock
        waits for nobody); returns the function that removes it."""
        ...

    @property
    def wall_start(self) -> float:
        """Unix time when the session's clock started."""
        ...

    def run(self, main: Coroutine[Any, Any, T]) -> T:
        """Run ``main`` on a fresh event loop keeping this clock's time."""
        ...

    def describe(self) -> dict[str, object]:
        """The clock as the session header records it (``source``, ``wall_start``, ...)."""
        ...


class RealClock:
    """The wall clock: ``time.monotonic`` for periods and deadlines, ``time.time`` for timestamps, asyncio's
    ordinary event loop (whose ``time()`` is ``time.monotonic()``). The robot always runs on it."""

    simulated: Final = False

    def __init__(self) -> None:
        self.wall_start = time.time()

    def monotonic(self) -> float:
        return time.monotonic()

    def now(self) -> float:
        return time.time()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))

    async def sleep_until(self, t: float) -> None:
        await asyncio.sleep(max(0.0, t - time.monotonic()))

    def timeout(self, seconds: float | None) -> asyncio.Timeout:
        return asyncio.timeout(seconds)

    async def wait(self, future: asyncio.Future[Any], seconds: float | None) -> bool:
        await asyncio.wait({future}, timeout=seconds)
        return future.done()

    def add_backlog(self, caught_up: CaughtUp) -> Callable[[], None]:
        """Nothing: the wall clock waits for nobody (a recorder that cannot keep up drops and counts)."""
        return _nothing

    def run(self, main: Coroutine[Any, Any, T]) -> T:
        """Run ``main`` on a fresh event loop of this clock (``asyncio.run``)."""
        return asyncio.run(main)

    def describe(self) -> dict[str, object]:
        """For the recording's session header."""
        return {"source": "wall", "wall_start": round(self.wall_start, 6)}


@dataclass(slots=True)
class _Parked:
    """A thread doing executor work that waits for simulated time to reach ``until``."""

    until: float
    woken: threading.Event


@dataclass(slots=True)
class _Work:
    """Executor work in flight: the thread or process's future and the loop's future it resolves."""

    done: concurrent.futures.Future[Any]
    result: asyncio.Future[Any]


class SimulatedClock:
    """Simulated time, advanced by the event loop it runs (``run``) when every task waits on the clock.

    ``speed`` is simulated seconds per wall second (None: as fast as the machine allows). ``wall_start`` is
    the Unix time that ``now()`` starts from (default: the wall clock when the clock is made), so published
    and recorded timestamps look like a real session's while advancing in simulated time."""

    simulated: Final = True

    def __init__(self, *, speed: float | None = None, wall_start: float | None = None) -> None:
        lo, hi = SPEED_RANGE
        if speed is not None and not (math.isfinite(speed) and lo <= speed <= hi):
            raise ValueError(
                f"speed {speed}: choose None (max) or {lo:g}-{hi:g} simulated seconds per second"
            )
        self.speed = speed
        self.wall_start = time.time() if wall_start is None else wall_start
        self._now = 0.0
        self._steppers: list[Callable[[float], None]] = []
        self._backlogs: list[CaughtUp] = []
        self._work: list[_Work] = []
        # Executor threads waiting on simulated time (``sleep_off_loop``), and the condition the loop waits
        # on for executor work: notified when a piece of work finishes or a thread starts waiting.
        self._parked: list[_Parked] = []
        self._work_changed = threading.Condition()
        self._closed = False  # the loop is closed: a thread waits on simulated time no more
        self._loop: _SimulatedLoop | None = None
        self._pace_wall = 0.0  # wall clock and simulated time of the last pacing anchor
        self._pace_sim = 0.0
        self.advances = 0  # how many times time moved (for benchmarks)
        self.held = 0  # how many times time waited for a helper that was behind (for benchmarks and tests)

    # --- Clock -------------------------------------------------------------------------------------------

    def monotonic(self) -> float:
        return self._now

    def now(self) -> float:
        return self.wall_start + self._now

    async def sleep(self, seconds: float) -> None:
        self._check_loop()
        await asyncio.sleep(max(0.0, seconds))

    async def sleep_until(self, t: float) -> None:
        loop = self._check_loop()
        if t <= self._now:
            await asyncio.sleep(0)
            return
        # At exactly ``t``: periodic loops on a simulated clock wake at their own grid, not one rounded to it.
        woken = loop.create_future()
        handle = loop.call_at(t, _wake, woken)
        try:
            await woken
        finally:
            handle.cancel()

    def timeout(self, seconds: float | None) -> asyncio.Timeout:
        self._check_loop()
        return asyncio.timeout(seconds)

    async def wait(self, future: asyncio.Future[Any], seconds: float | None) -> bool:
        self._check_loop()
        await asyncio.wait({future}, timeout=seconds)
        return future.done()

    def sleep_off_loop(self, until: float) -> None:
        """From a thread doing executor work for this clock's loop (``run_in_executor``,
        ``asyncio.to_thread``): block until simulated time reaches ``until``, as a computation that takes
        that long would. Meanwhile the work counts as waiting on the clock, not as work in flight: time moves
        on and the loop's tasks (polls, timers, telemetry) run through it; when time reaches ``until`` the
        thread goes on before anything else runs at that time, and the loop waits for it as for any work.
        Returns at once at or past ``until``, once the loop is closed, and on any thread but one doing this
        clock's executor work in a thread pool (the loop would not know to wait for it; the loop's own
        thread cannot wait for itself). The wait depends on simulated time only, never on this machine's
        load."""
        if getattr(_this_thread, "work_of", None) is not self:
            return  # not this clock's executor work (the loop's own thread, another thread): cannot wait
        with self._work_changed:
            if self._closed or until <= self._now:
                return
            parked = _Parked(until, threading.Event())
            self._parked.append(parked)
            self._work_changed.notify_all()
        parked.woken.wait()

    def add_stepper(self, step: Callable[[float], None]) -> Callable[[], None]:
        self._steppers.append(step)

        def remove() -> None:
            if step in self._steppers:
                self._steppers.remove(step)

        return remove

    def add_backlog(self, caught_up: CaughtUp) -> Callable[[], None]:
        """Before time moves on, wait until ``caught_up(wait_s)`` says the helper is no longer behind (it
        waits up to ``wait_s`` wall seconds; input from outside is handled meanwhile). The recorder's queue
        is one: in simulation nothing is dropped, and what is recorded does not depend on this machine's
        speed. Returns the function that removes it."""
        self._backlogs.append(caught_up)

        def remove() -> None:
            if caught_up in self._backlogs:
                self._backlogs.remove(caught_up)

        return remove

    # --- running ------------------------------------------------------------------------------------------

    def run(self, main: Coroutine[Any, Any, T]) -> T:
        """Run ``main`` on this clock's event loop until it returns (like ``asyncio.run``)."""
        with asyncio.Runner(loop_factory=self._new_loop) as runner:
            return runner.run(main)

    def describe(self) -> dict[str, object]:
        """For the recording's session header: simulated time, its speed and the wall-clock start."""
        return {
            "source": "simulated",
            "speed": describe_speed(self.speed),
            "wall_start": round(self.wall_start, 6),
        }

    def _new_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is not None and not self._loop.is_closed():
            raise RuntimeError("a SimulatedClock drives one event loop at a time; this one is running")
        self._loop = _SimulatedLoop(self)
        with self._work_changed:
            self._closed = False
        self._pace_wall, self._pace_sim = time.monotonic(), self._now
        return self._loop

    def _check_loop(self) -> asyncio.AbstractEventLoop:
        loop = asyncio.get_running_loop()
        if loop is not self._loop:
            raise RuntimeError(
                "this coroutine waits on a SimulatedClock but runs on another event loop; run it with "
                "SimulatedClock.run(...)"
            )
        return loop

    # --- called by the loop ---------------------------------------------------------------------------

    def _submit(self, executor: Executor, fn: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        assert self._loop is not None
        if isinstance(executor, ThreadPoolExecutor):
            done = executor.submit(_as_work_of, self, fn, *args)
        else:
            done = executor.submit(fn, *args)
        result: asyncio.Future[T] = self._loop.create_future()

        def cancelled(f: asyncio.Future[T]) -> None:
            if f.cancelled():
                done.cancel()  # not started yet: it never will; started: it finishes, unseen

        result.add_done_callback(cancelled)
        self._work.append(_Work(done, result))
        done.add_done_callback(self._notify_work)
        return result

    def _notify_work(self, _: object) -> None:
        with self._work_changed:
            self._work_changed.notify_all()

    def _first_wake(self) -> float | None:
        """The earliest simulated time a thread waits for (``sleep_off_loop``); None when none waits."""
        if not self._parked:  # the common case, asked at every step of time: no lock (see ``_select``)
            return None
        with self._work_changed:
            return min((p.until for p in self._parked), default=None)

    def _wake_parked(self, t: float) -> bool:
        """Let the threads waiting for simulated time ``t`` (or earlier) go on; whether any did."""
        if not self._parked:
            return False
        with self._work_changed:
            woken = [p for p in self._parked if p.until <= t]
            self._parked = [p for p in self._parked if p.until > t]
        for p in woken:
            p.woken.set()
        return bool(woken)

    def _loop_closed(self) -> None:
        """The loop is closed: threads waiting on simulated time go on, and none waits any more."""
        with self._work_changed:
            self._closed = True
            parked, self._parked = self._parked, []
        for p in parked:
            p.woken.set()

    def _select(
        self, select: Callable[[float | None], list[tuple[selectors.SelectorKey, int]]], timeout: float | None
    ) -> list[tuple[selectors.SelectorKey, int]]:
        """The loop's wait for I/O, where simulated time is made: ``timeout`` is 0 when callbacks are ready,
        the time to the next timer, or None when no timer is set.

        I/O that is ready is handled first, at the current time (the in-process devices write from this
        thread, so what they sent is always there by the next look). Then executor work in flight is waited
        for and handed back; only when there is neither does time move on. From then on no thread can
        start waiting on the clock (only executor work in flight does, and all of it has finished or is
        waiting already), so ``_parked`` may be looked at without the lock."""
        ready = select(0)
        if ready or timeout == 0:
            return ready
        if self._work:
            in_flight = len(self._work)
            outside = self._finish_work(select)
            if outside is not None:
                return outside
            if len(self._work) < in_flight:
                return select(0)  # work handed back: the loop runs what it resolved, at this time
            # Every piece of work in flight waits on the clock (``sleep_off_loop``): time moves on.
        wake = self._first_wake()
        if timeout is None and wake is None:
            return select(None)  # no timer at all: only the outside world can wake the loop
        target = self._now + timeout if timeout is not None else math.inf
        if wake is not None:
            target = min(target, wake)
        if self.speed is not None:
            wait = self._paced_wait(target)
            if wait > 0:
                ready = select(wait)
                if ready or self._paced_wait(target) > 0:
                    return ready  # input from outside (or woken early): time stays where it is
        held = self.held
        outside = self._catch_up(select)
        if outside is not None:
            return outside
        if self.held != held:
            ready = select(0)  # what a helper handed back as it caught up (a callback) comes at this time
            if ready:
                return ready
        self._advance(target)
        if self._wake_parked(target):
            # The threads whose time came go on first: until they finish or wait again, nothing else runs.
            outside = self._finish_work(select)
            return outside if outside is not None else select(0)
        # No second look for I/O: nothing on this thread wrote any since the look above (the world's
        # steppers write to no device), and input from outside is taken at the next look, at this time.
        return []

    def _catch_up(
        self, select: Callable[[float | None], list[tuple[selectors.SelectorKey, int]]]
    ) -> list[tuple[selectors.SelectorKey, int]] | None:
        """Wait until no helper is behind; None when none is, or what came in from outside meanwhile
        (handled first, at the current time)."""
        for caught_up in list(self._backlogs):
            held = False
            while not caught_up(_EXTERNAL_POLL_S):
                if not held:
                    held = True
                    self.held += 1
                ready = select(0)
                if ready:
                    return ready
        return None

    def _finish_work(
        self, select: Callable[[float | None], list[tuple[selectors.SelectorKey, int]]]
    ) -> list[tuple[selectors.SelectorKey, int]] | None:
        """Wait until every piece of executor work in flight has finished or waits on the clock
        (``sleep_off_loop``), then resolve the futures of those finished in submission order (those waiting
        stay in flight); None when done, or what came in from outside meanwhile (a command, a signal, a
        callback a thread handed the loop; looked for every ``_EXTERNAL_POLL_S``), which is handled first
        while the work stays in flight."""
        work = self._work
        while True:
            with self._work_changed:
                running = sum(1 for w in work if not w.done.done())
                if running <= len(self._parked):
                    break
                self._work_changed.wait(_EXTERNAL_POLL_S)
            ready = select(0)
            if ready:
                return ready
        self._work = [w for w in work if not w.done.done()]
        for w in work:
            if not w.done.done() or w.result.done() or w.done.cancelled():
                continue
            error = w.done.exception()
            if error is not None:
                w.result.set_exception(error)
            else:
                w.result.set_result(w.done.result())
        return None

    def _paced_wait(self, target: float) -> float:
        """Wall seconds still to wait before simulated time may reach ``target`` at ``speed``."""
        assert self.speed is not None
        wall = time.monotonic()
        due = self._pace_wall + (target - self._pace_sim) / self.speed
        if wall - due > _BEHIND_S:
            self._pace_wall, self._pace_sim = wall, self._now
            due = wall + (target - self._now) / self.speed
        return due - wall

    def _advance(self, target: float) -> None:
        self._now = target
        self.advances += 1
        for step in list(self._steppers):
            step(target)


def _nothing() -> None:
    return None


# Which clock's executor work this thread is doing (``work_of``), for ``SimulatedClock.sleep_off_loop``.
_this_thread = threading.local()


def _as_work_of(clock: SimulatedClock, fn: Callable[..., T], *args: Any) -> T:
    """Run ``fn`` in a pool thread as ``clock``'s executor work."""
    _this_thread.work_of = clock
    try:
        return fn(*args)
    finally:
        _this_thread.work_of = None


def _wake(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


class _Selector(selectors.DefaultSelector):
    """The platform's selector, whose ``select`` lets the simulated clock decide how time passes."""

    def __init__(self, clock: SimulatedClock) -> None:
        super().__init__()
        self._clock = clock

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        return self._clock._select(super().select, timeout)


class _SimulatedLoop(asyncio.SelectorEventLoop):
    """asyncio's selector loop with the simulated clock's time and its executor bookkeeping."""

    def __init__(self, clock: SimulatedClock) -> None:
        super().__init__(selector=_Selector(clock))
        self._clock = clock
        self._pool = ThreadPoolExecutor(thread_name_prefix="simulated-executor")
        self.set_default_executor(self._pool)

    def time(self) -> float:
        return self._clock.monotonic()

    def close(self) -> None:
        self._clock._loop_closed()
        super().close()

    def run_in_executor(
        self, executor: Executor | None, func: Callable[[*Ts], T], *args: *Ts
    ) -> asyncio.Future[T]:
        if self.is_closed():
            raise RuntimeError("Event loop is closed")
        return self._clock._submit(self._pool if executor is None else executor, func, *args)


__all__ = [
    "SPEED_RANGE",
    "CaughtUp",
    "RealClock",
    "SessionClock",
    "SimulatedClock",
    "describe_speed",
    "parse_speed",
    "wall_seconds",
]
