"""The servo chain as an asyncio resource: the blocking bus lives on its own thread.

Every bus transaction runs on one dedicated thread, in submission order, so the event loop never waits on
the serial port and the SDK's state is touched by one thread only. Fault events raised on that thread are
handed to the event loop with ``call_soon_threadsafe``.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from types import TracebackType
from typing import TypeVar

from drivers.dynamixel.bus import DeviceEvent, DynamixelBus, ServoCounters
from drivers.dynamixel.config import BusConfig

T = TypeVar("T")


class ServoChain:
    """An open, verified servo chain. ``async with ServoChain(config, expected) as chain: ...``

    ``expected`` lists every (servo id, model) on the chain; entering checks them all and raises one
    ``ChainMismatch`` naming every problem, before any torque is enabled. ``on_event`` receives fault and
    recovery events on the event loop.
    """

    def __init__(
        self,
        config: BusConfig,
        expected: Sequence[tuple[int, str]],
        *,
        retries: int = 2,
        read_timeout_s: float = 0.02,
        on_event: Callable[[DeviceEvent], None] | None = None,
    ) -> None:
        self.config = config
        self.expected = tuple(expected)
        self._on_event = on_event
        self._loop: asyncio.AbstractEventLoop | None = None
        self.bus = DynamixelBus(
            config, retries=retries, read_timeout_s=read_timeout_s, on_event=self._forward
        )
        self._executor: ThreadPoolExecutor | None = None

    def _forward(self, event: DeviceEvent) -> None:
        if self._on_event is not None and self._loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closing: nobody is left to tell
                self._loop.call_soon_threadsafe(self._on_event, event)

    async def call(self, fn: Callable[[DynamixelBus], T]) -> T:
        """Run ``fn(bus)`` on the bus thread and return its result (exceptions propagate)."""
        if self._executor is None or self._loop is None:
            raise RuntimeError("the servo chain is not open; use `async with ServoChain(...)`")
        return await self._loop.run_in_executor(self._executor, fn, self.bus)

    def counters(self) -> dict[int, ServoCounters]:
        """A snapshot of the per-servo timeout/corrupt/retry/fault counters (for status publishing)."""
        return {i: dataclasses.replace(c) for i, c in self.bus.counters.items()}

    def faulted(self) -> dict[int, tuple[str, ...]]:
        """Servos whose last answer carried a fault, with the fault names."""
        return self.bus.faulted()

    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dynamixel-bus")
        try:
            await self.call(lambda bus: bus.open())
            await self.call(lambda bus: bus.verify(self.expected))
        except BaseException:
            await self.close()
            raise

    async def close(self) -> None:
        if self._executor is None:
            return
        try:
            await self.call(lambda bus: bus.close())
        finally:
            self._executor.shutdown(wait=True)
            self._executor = None

    async def __aenter__(self) -> ServoChain:
        await self.open()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()
