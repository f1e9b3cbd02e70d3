"""A simulated FSR Arduino on a pseudo-terminal: the sketch's exact lines at 100 Hz, driven by the world.

``force_n`` is called for every sample (from the simulator's thread) and converted to the ADC count the
10 kOhm divider would give. Fault hooks silence the stream, inject garbage or torn lines, corrupt
checksums, force a drop to zero or a one-sample spike, and unplug the adapter.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from drivers.fsr import protocol
from drivers.sim.pty_link import PtyDevice


class FsrSimulator(PtyDevice):
    """Streams ``$FSR,seq,raw*HH`` lines on a pty and answers ``?V``; open :attr:`device_path`."""

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
        assert self._link is not None
        link = self._link
        query = bytearray()
        next_t = time.monotonic()
        while not self._stop.is_set():
            incoming = link.read(max(0.0, next_t - time.monotonic()))
            query += incoming
            if b"\n" in query:
                lines = bytes(query).split(b"\n")
                query = bytearray(lines[-1])
                if any(line.strip() == b"?V" for line in lines[:-1]):
                    link.write(protocol.version_line(self.version))
            if time.monotonic() < next_t:
                continue
            next_t += self.period_s
            if next_t < time.monotonic():  # fell behind (a paused thread): do not burst
                next_t = time.monotonic() + self.period_s
            link.write(self._next_line())

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
