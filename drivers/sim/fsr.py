"""A simulated FSR Arduino: the sketch's exact lines at 100 Hz, driven by the world.

``force_n`` is called for every sample and converted to the ADC count the 10 kOhm divider would give. On a
pseudo-terminal (``start()``) a thread streams in wall-clock time; in-process (``start_in_process(clock)``)
an asyncio task streams on the clock, so on a simulated clock every sample carries the world's force at
exactly its 10 ms tick. Fault hooks silence the stream, inject garbage or torn lines, corrupt checksums,
force a drop to zero or a one-sample spike, and unplug the adapter.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from drivers.fsr import protocol
from drivers.interfaces import Clock
from drivers.sim.device import SimulatedDevice
from drivers.sim.pty_link import PtyLink


class FsrSimulator(SimulatedDevice):
    """Streams ``$FSR,seq,raw*HH`` lines and answers ``?V``; open :attr:`device_path`."""

    streams = True

    def __init__(
        self,
        force_n: Callable[[], float],
        *,
        rate_hz: float = 100.0,
        version: str = "1",
        name: str = "ttyFSR",
    ) -> None:
        self._force_n = force_n
        self.period_s = 1.0 / rate_hz
        self.version = version
        super().__init__(name, thread_name="fsr-sim")
        self._lock = threading.Lock()
        self._seq = 0
        self._silent = False
        self._dropped = False
        self._spikes: list[float] = []
        self._garbage = b""
        self._bad_checksums = 0
        self._torn = 0
        self._query = bytearray()
        self.lines_sent = 0

    # ------------------------------------------------------------------------------------------ fault hooks

    def silence(self, on: bool = True) -> None:
        """Stop (or resume) streaming, as a hung sketch would."""
        with self._lock:
            self._silent = on

    def drop_force(self, on: bool = True) -> None:
        """Report zero force regardless of the world: the mug slipped out of the gripper."""
        with self._lock:
            self._dropped = on

    def spike(self, force_n: float, *, samples: int = 1) -> None:
        """Replace the next ``samples`` readings with ``force_n`` (an electrical spike)."""
        with self._lock:
            self._spikes.extend([force_n] * samples)

    def inject_garbage(self, data: bytes) -> None:
        with self._lock:
            self._garbage += data

    def bad_checksums(self, lines: int = 1) -> None:
        with self._lock:
            self._bad_checksums += lines

    def tear_lines(self, lines: int = 1) -> None:
        """Send only the first half of the next ``lines`` lines."""
        with self._lock:
            self._torn += lines

    # ------------------------------------------------------------------------------------------ serving

    def _serve(self) -> None:
        assert isinstance(self._link, PtyLink)
        link = self._link
        next_t = time.monotonic()
        while not self._stop.is_set():
            self._received(link.read(max(0.0, next_t - time.monotonic())))
            if time.monotonic() < next_t:
                continue
            next_t += self.period_s
            if next_t < time.monotonic():  # fell behind (a paused thread): do not burst
                next_t = time.monotonic() + self.period_s
            link.write(self._next_line())

    def _received(self, data: bytes) -> None:
        """Answer the version query (``?V``) as the sketch does."""
        link = self._link
        with self._lock:
            self._query += data
            if b"\n" not in self._query:
                return
            lines = bytes(self._query).split(b"\n")
            self._query = bytearray(lines[-1])
        if link is not None and any(line.strip() == b"?V" for line in lines[:-1]):
            link.write(protocol.version_line(self.version))

    async def _run_on(self, clock: Clock) -> None:
        next_t = clock.monotonic()
        while True:
            await clock.sleep_until(next_t)
            if self._link is not None:
                self._link.write(self._next_line())
            next_t += self.period_s

    def _next_line(self) -> bytes:
        with self._lock:
            if self._silent:
                return b""
            force = 0.0 if self._dropped else self._force_n()
            if self._spikes:
                force = self._spikes.pop(0)
            line = protocol.sample_line(self._seq, protocol.raw_from_force(force))
            self._seq += 1
            garbage, self._garbage = self._garbage, b""
            if self._bad_checksums:
                self._bad_checksums -= 1
                star = line.index(b"*")
                line = line[: star + 1] + (b"00" if line[star + 1 : star + 3] != b"00" else b"11") + b"\r\n"
            if self._torn:
                self._torn -= 1
                line = line[: len(line) // 2]
            self.lines_sent += 1
            return garbage + line
