"""The servo chain as an asyncio resource: the blocking bus lives on its own thread.

Every bus transaction runs on one dedicated thread, in submission order, so the event loop never waits on
the serial port and the SDK's state is touched by one thread only. Fault events raised during a
transaction reach the listener on the event loop when the transaction returns, before its result: in the
order they happened and at the same point of the job however the threads were scheduled (which keeps a
simulated run deterministic).

``inline=True`` runs each transaction on the event loop's own thread instead. That is for an in-process
cable on a simulated clock only (the simulated cell): the simulator has answered before the driver starts
reading, so a transaction never waits on a device, and no simulated time passes while one runs either way.
It saves the thread hop of every transaction (tens of thousands a job), with the same events in the same
order.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from types import TracebackType
from typing import TypeVar

from drivers.dynamixel.bus import DeviceEvent, DynamixelBus, ServoCounters
from drivers.dynamixel.config import BusConfig
from drivers.interfaces import Clock
from drivers.serial_port import OpenSerial

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
        self._events: _Events | None = None  # the running transaction's (only the bus thread sets it)
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

    def _forward(self, event: DeviceEvent) -> None:
        events = self._events
        if events is not None:
            events.add(event)

    async def call(self, fn: Callable[[DynamixelBus], T]) -> T:
        """Run ``fn(bus)`` on the bus thread and return its result (exceptions propagate); the events it
        raised reach the listener first."""
        if not self._open or self._loop is None:
            raise RuntimeError("the servo chain is not open; use `async with ServoChain(...)`")
        events = _Events(self._loop, self._on_event)
        if self.inline:  # on the loop's thread
            self._events = events
            try:
                return fn(self.bus)
            finally:
                self._events = None
                events.deliver()

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

    def counters(self) -> dict[int, ServoCounters]:
        """A snapshot of the per-servo timeout/corrupt/retry/fault counters (for status publishing)."""
        return {i: dataclasses.replace(c) for i, c in self.bus.counters.items()}

    def faulted(self) -> dict[int, tuple[str, ...]]:
        """Servos whose last answer carried a fault, with the fault names."""
        return self.bus.faulted()

    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        if not self.inline:
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
