"""The servo chain as an asyncio resource: the blocking bus lives on its own thread.

Every bus transaction runs on one dedicated thread, in submission order, so the event loop never waits on
the serial port and the SDK's state is touched by one thread only. Fault events raised during a
transaction reach the listener on the event loop when the transaction returns, before its result: in the
order they happened and at the same point of the job however the threads were scheduled (which keeps a
simulated run deterministic).

``inline=True`` is for an in-process cable on a simulated clock only (the simulated cells). While the
simulator answers everything at once (``DynamixelBus.answers_at_once``: no servo silent, dropping or
garbling answers), each transaction runs on the event loop's own thread: it never waits on a device and
takes no simulated time, and it saves the thread hop of every transaction (tens of thousands a job). When a
fault withholds answers, the transaction runs on a thread of its own that takes turns with the loop: the
loop waits while it runs, and each wait of the bus (a status packet's timeout before a retry, a pause) lets
that much simulated time pass on the loop, so the world moves and faults begin and end meanwhile, as they
would while the robot's bus waits. A servo silent for a moment is then bridged by the retries; one that
stays silent faults once they are spent. Transactions keep their order either way, with the same events.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import select
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from types import TracebackType
from typing import TypeVar, cast

from drivers.dynamixel.bus import DeviceEvent, DynamixelBus, ServoCounters
from drivers.dynamixel.config import BusConfig
from drivers.interfaces import Clock
from drivers.serial_port import OpenSerial, SerialPort

T = TypeVar("T")
EventListener = Callable[[DeviceEvent], None]


class _Events:
    """The events of one transaction: kept until the loop takes them when the transaction returns; a
    transaction nobody waits for any more (cancelled) hands later ones to the loop itself."""

    def __init__(self, loop: asyncio.AbstractEventLoop, listener: EventListener | None) -> None:
        self._loop = loop
        self._listener = listener
        self._lock = threading.Lock()
        self._kept: list[DeviceEvent] = []
        self._taken = False

    def add(self, event: DeviceEvent) -> None:
        with self._lock:
            if not self._taken:
                self._kept.append(event)
                return
        if self._listener is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closing: nobody is left to tell
                self._loop.call_soon_threadsafe(self._listener, event)

    def deliver(self) -> None:
        with self._lock:
            self._taken = True
            kept, self._kept = self._kept, []
        if self._listener is not None:
            for event in kept:
                self._listener(event)


class _Kept:
    """The events of a transaction run at once on the loop's thread, handed over when it returns."""

    __slots__ = ("events",)

    def __init__(self) -> None:
        self.events: list[DeviceEvent] = []

    def add(self, event: DeviceEvent) -> None:
        self.events.append(event)

    def deliver(self, listener: EventListener | None) -> None:
        events, self.events = self.events, []
        if listener is not None:
            for event in events:
                listener(event)


def _readable_now(port: SerialPort) -> bool:
    """Whether ``port`` has bytes to read (or reads end-of-file) now: an in-process port says so itself
    (``InProcessPort.pending``, no system call), any other is asked with ``select``."""
    pending = getattr(port, "pending", None)
    if pending is not None:
        return bool(pending())
    return bool(select.select([port.fileno()], [], [], 0)[0])


class _InstantWaits:
    """The bus's waits while the in-process simulator answers at once: what has not arrived will not, and
    no time passes (the clock's)."""

    def __init__(self, clock: Clock) -> None:
        self._clock = clock

    def now(self) -> float:
        return self._clock.monotonic()

    def readable(self, port: SerialPort, timeout_s: float) -> bool:
        return _readable_now(port)

    def sleep(self, seconds: float) -> None:
        return None


class _Turns:
    """A transaction on its own thread taking turns with the event loop: the thread runs while the loop
    waits for its next outcome; a wait of the bus (``park``) hands the turn back until the loop has let
    that much simulated time pass (``resume``). ``abandon`` lets the rest run without waiting."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._outcome: tuple[str, object] | None = None  # ("wait", until) | ("done", result) | ("error", e)
        self._abandoned = False

    # --- the transaction's thread ----------------------------------------------------------------------

    def park(self, until: float) -> None:
        with self._cond:
            if self._abandoned:
                return
            self._outcome = ("wait", until)
            self._cond.notify_all()
            self._cond.wait_for(lambda: self._outcome is None)

    def finish(self, outcome: tuple[str, object]) -> None:
        with self._cond:
            self._outcome = outcome
            self._cond.notify_all()

    # --- the loop's thread -----------------------------------------------------------------------------

    def next_outcome(self) -> tuple[str, object]:
        """Block until the transaction waits or ends (it runs meanwhile): what it did."""
        with self._cond:
            self._cond.wait_for(lambda: self._outcome is not None)
            assert self._outcome is not None
            return self._outcome

    def resume(self) -> None:
        with self._cond:
            self._outcome = None
            self._cond.notify_all()

    def abandon(self) -> None:
        with self._cond:
            self._abandoned = True
            if self._outcome is not None and self._outcome[0] == "wait":
                self._outcome = None
                self._cond.notify_all()


class _SimulatedWaits:
    """The bus's waits on the clock's simulated time, for a transaction taking turns with the loop."""

    def __init__(self, clock: Clock, turns: _Turns) -> None:
        self._clock = clock
        self._turns = turns

    def now(self) -> float:
        return self._clock.monotonic()

    def readable(self, port: SerialPort, timeout_s: float) -> bool:
        if _readable_now(port):
            return True
        self._turns.park(self._clock.monotonic() + timeout_s)
        return _readable_now(port)

    def sleep(self, seconds: float) -> None:
        self._turns.park(self._clock.monotonic() + seconds)


class ServoChain:
    """An open, verified servo chain. ``async with ServoChain(config, expected) as chain: ...``

    ``expected`` lists every (servo id, model) on the chain; entering checks them all and raises one
    ``ChainMismatch`` naming every problem, before any torque is enabled. ``on_event`` receives fault and
    recovery events on the event loop. ``open_serial`` opens the port (default: pyserial on the device
    file; an in-process simulator's in the simulated cell).
    """

    def __init__(
        self,
        config: BusConfig,
        expected: Sequence[tuple[int, str]],
        *,
        clock: Clock,
        retries: int = 2,
        read_timeout_s: float = 0.02,
        corrupt_rate_max: float = 0.2,
        corrupt_window: int = 50,
        on_event: EventListener | None = None,
        open_serial: OpenSerial | None = None,
        inline: bool = False,
    ) -> None:
        self.config = config
        self.inline = inline
        self._open = False
        self.expected = tuple(expected)
        self.clock = clock
        self._on_event = on_event
        self._loop: asyncio.AbstractEventLoop | None = None
        # The running transaction's events (only the thread running it sets this).
        self._events: _Events | _Kept | None = None
        self._kept = _Kept()  # those of a transaction run at once on the loop's thread
        self.bus = DynamixelBus(
            config,
            clock=clock,
            retries=retries,
            read_timeout_s=read_timeout_s,
            corrupt_rate_max=corrupt_rate_max,
            corrupt_window=corrupt_window,
            on_event=self._forward,
            open_serial=open_serial,
        )
        self._executor: ThreadPoolExecutor | None = None
        self._instant = _InstantWaits(clock)
        self._turn: asyncio.Lock | None = None  # inline: one transaction at a time, in submission order

    def _forward(self, event: DeviceEvent) -> None:
        events = self._events
        if events is not None:
            events.add(event)

    async def call(self, fn: Callable[[DynamixelBus], T]) -> T:
        """Run ``fn(bus)`` on the bus thread and return its result (exceptions propagate); the events it
        raised reach the listener first."""
        if not self._open or self._loop is None:
            raise RuntimeError("the servo chain is not open; use `async with ServoChain(...)`")
        if self.inline:
            assert self._turn is not None
            async with self._turn:
                if self.bus.answers_at_once():  # on the loop's thread, taking no time
                    return self._at_once(fn)
                return await self._taking_turns(fn, _Events(self._loop, self._on_event))
        events = _Events(self._loop, self._on_event)

        def transaction(bus: DynamixelBus) -> T:
            self._events = events
            try:
                return fn(bus)
            finally:
                self._events = None

        try:
            return await self._loop.run_in_executor(self._executor, transaction, self.bus)
        finally:
            events.deliver()

    def _at_once(self, fn: Callable[[DynamixelBus], T]) -> T:
        """Run ``fn(bus)`` here, on the loop's thread, while the device answers at once; the events it
        raised reach the listener when it returns (nothing can come between: it runs to the end)."""
        kept = self._kept
        self._events = kept
        self.bus.waits = self._instant
        try:
            return fn(self.bus)
        finally:
            self._events = None
            if kept.events:
                kept.deliver(self._on_event)

    async def _taking_turns(self, fn: Callable[[DynamixelBus], T], events: _Events) -> T:
        """Run ``fn(bus)`` on the bus thread taking turns with the loop: the loop is held while it runs, and
        its waits on the device pass in the clock's time (``_Turns``)."""
        assert self._executor is not None
        turns = _Turns()

        def transaction() -> None:
            self._events = events
            self.bus.waits = _SimulatedWaits(self.clock, turns)
            outcome: tuple[str, object]
            try:
                outcome = ("done", fn(self.bus))
            except BaseException as e:
                outcome = ("error", e)
            # Before the loop has its turn back: the next transaction may start at once.
            self._events = None
            turns.finish(outcome)

        self._executor.submit(transaction)
        try:
            while True:
                kind, value = turns.next_outcome()
                if kind == "wait":
                    assert isinstance(value, float)
                    try:
                        await self.clock.sleep_until(value)
                    except BaseException:
                        # Cancelled while the bus waits: the rest of the transaction runs without waiting,
                        # so the bus is left between transactions for the next caller.
                        turns.abandon()
                        turns.next_outcome()
                        raise
                    turns.resume()
                    continue
                if kind == "error":
                    assert isinstance(value, BaseException)
                    raise value
                return cast(T, value)  # what fn returned
        finally:
            events.deliver()

    def counters(self) -> dict[int, ServoCounters]:
        """A snapshot of the per-servo timeout/corrupt/retry/fault counters (for status publishing)."""
        return {i: dataclasses.replace(c) for i, c in self.bus.counters.items()}

    def faulted(self) -> dict[int, tuple[str, ...]]:
        """Servos whose last answer carried a fault, with the fault names."""
        return self.bus.faulted()

    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._turn = asyncio.Lock()
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dynamixel-bus")
        self._open = True
        try:
            await self.call(lambda bus: bus.open())
            await self.call(lambda bus: bus.verify(self.expected))
        except BaseException:
            await self.close()
            raise

    async def close(self) -> None:
        if not self._open:
            return
        try:
            await self.call(lambda bus: bus.close())
        finally:
            self._open = False
            executor, self._executor = self._executor, None
            if executor is not None:
                executor.shutdown(wait=True)

    async def __aenter__(self) -> ServoChain:
        await self.open()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()
