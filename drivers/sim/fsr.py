"""A simulated FSR Arduino: the sketch's exact lines at 100 Hz, driven by the world.

``force_n`` is called for every sample and converted to the ADC count the 10 kOhm divider would give. On a
pseudo-terminal (``start()``) a thread streams in wall-clock time; in-process (``start_in_process(clock)``)
an asyncio task streams on the clock, so on a simulated clock every sample carries the world's force at
exactly its 10 ms tick. Fault hooks silence the stream, inject garbage or torn lines, corrupt checksums,
force a drop to zero or a one-sample spike, and unplug the adapter.

In-process, a tap (``tap_samples``) may take a sample instead of its line: a replay's stand-in hands the
reader each sample at its tick while the replay serves the recorded force, skipping the bytes (formatting,
the cable, parsing) but not the world's force at each tick nor the reader's state.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from drivers.fsr import protocol
from drivers.interfaces import Clock
from drivers.sim.device import DeviceLink, SimulatedDevice
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
        self._tap: Callable[[protocol.Sample], bool] | None = None
        self.lines_sent = 0
        self.samples_tapped = 0  # samples a tap took instead of their lines

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

    def tap_samples(self, take: Callable[[protocol.Sample], bool] | None) -> None:
        """In-process: offer each sample to ``take`` first; the line goes out only when it returns False
        (None: every sample as its line again). The sample is the one the line would carry, taken at the
        same tick, with the same force and sequence number; line faults (garbage, checksums, torn lines)
        wait for the next line sent."""
        self._tap = take

    async def _run_on(self, clock: Clock) -> None:
        next_t = clock.monotonic()
        while True:
            await clock.sleep_until(next_t)
            if self._link is not None:
                self._send(self._link, self._next_sample())
            next_t += self.period_s

    def _send(self, link: DeviceLink, sample: protocol.Sample | None) -> None:
        """``sample`` to the tap when it takes it, else its line on ``link`` (nothing while silent)."""
        if sample is None:
            return
        tap = self._tap
        if tap is not None and tap(sample):
            self.samples_tapped += 1
            return
        link.write(self._framed(sample))

    def _next_line(self) -> bytes:
        sample = self._next_sample()
        return b"" if sample is None else self._framed(sample)

    def _next_sample(self) -> protocol.Sample | None:
        """The sketch's next reading of the world's force (None while it is silent)."""
        with self._lock:
            if self._silent:
                return None
            force = 0.0 if self._dropped else self._force_n()
            if self._spikes:
                force = self._spikes.pop(0)
            sample = protocol.Sample(self._seq % protocol.SEQ_MODULO, protocol.raw_from_force(force))
            self._seq += 1
            return sample

    def _framed(self, sample: protocol.Sample) -> bytes:
        """``sample``'s line as sent, with whatever line faults are due."""
        with self._lock:
            line = protocol.sample_line(sample.seq, sample.raw)
            self.lines_sent += 1
            garbage, self._garbage = self._garbage, b""
            if self._bad_checksums:
                self._bad_checksums -= 1
                star = line.index(b"*")
                line = line[: star + 1] + (b"00" if line[star + 1 : star + 3] != b"00" else b"11") + b"\r\n"
            if self._torn:
                self._torn -= 1
                line = line[: len(line) // 2]
            return garbage + line
