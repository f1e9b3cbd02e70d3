"""A non-blocking asyncio reader of the FSR sketch, implementing ``drivers.interfaces.ForceSensor``.

The serial port is read from the event loop's selector (``loop.add_reader``), never with a blocking call.
Each valid line becomes a sample; a median of three rejects single-sample spikes; grasp detection uses a
threshold with hysteresis and a debounce time (§4.3.1); while the daemon says a mug is being carried, a
debounced release is reported as a drop (§3.2.2.2). Garbage, torn lines and bad checksums are counted and
skipped. When the adapter disappears the port is closed and reopened every ``reconnect_period_s`` until the
Arduino is back; :meth:`check` raises :class:`SensorFault` while no fresh sample arrives. Samples are stamped,
debounced and aged on the ``Clock`` the reader is given.
"""

from __future__ import annotations

import asyncio
import contextlib
import statistics
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

import serial
import structlog

from drivers.dynamixel.bus import DeviceEvent
from drivers.errors import SensorFault
from drivers.fsr import protocol
from drivers.interfaces import Clock, ForceReading
from drivers.serial_port import OpenSerial, SerialPort, open_pyserial

log = structlog.get_logger("drivers.fsr")


@dataclass(slots=True)
class FsrCounters:
    """What the reader had to throw away or could not see, since it started."""

    samples: int = 0
    bad_lines: int = 0
    lost_samples: int = 0  # sequence-number gaps
    spikes: int = 0
    reconnects: int = 0


class FsrReader:
    """The gripper pad's force, read from the FSR Arduino on ``port`` (opened with ``open_serial``: pyserial
    by default, an in-process simulator's in the simulated cell)."""

    def __init__(
        self,
        port: str,
        *,
        clock: Clock,
        threshold_n: float = 2.0,
        release_n: float | None = None,
        debounce_s: float = 0.03,
        spike_n: float = 4.0,
        gain: float = 1.0,
        stale_after_s: float = 0.2,
        reconnect_period_s: float = 0.2,
        version_timeout_s: float = 1.0,
        baudrate: int = 115_200,
        on_event: Callable[[DeviceEvent], None] | None = None,
        open_serial: OpenSerial = open_pyserial,
    ) -> None:
        release = threshold_n * 0.6 if release_n is None else release_n
        if not 0 <= release < threshold_n:
            raise ValueError(f"fsr.release_n {release} must be in [0, threshold_n={threshold_n})")
        if debounce_s < 0 or spike_n <= 0 or gain <= 0 or stale_after_s <= 0:
            raise ValueError("fsr.debounce_s must be >= 0 and spike_n, gain, stale_after_s > 0")
        self.port = port
        self.clock = clock
        self._open_serial = open_serial
        self.threshold_n = threshold_n
        self.release_n = release
        self.debounce_s = debounce_s
        self.spike_n = spike_n
        self.gain = gain
        self.stale_after_s = stale_after_s
        self.reconnect_period_s = reconnect_period_s
        self.version_timeout_s = version_timeout_s
        self.baudrate = baudrate
        self._on_event = on_event
        self.counters = FsrCounters()
        self.firmware_version: str | None = None
        self._serial: SerialPort | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._buf = bytearray()
        self._window: deque[float] = deque(maxlen=3)
        self._latest: ForceReading | None = None
        self._last_seq: int | None = None
        self._holding = False
        self._pending_since: float | None = None
        self._carrying = False
        self._dropped = False
        self._lost = False
        self._reconnect: asyncio.Task[None] | None = None
        self._watchdog: asyncio.Task[None] | None = None
        self._stale = False
        self._version_seen = asyncio.Event()
        self._log = log.bind(port=port)

    # ------------------------------------------------------------------------------------------ lifecycle

    async def start(self) -> None:
        """Open the port and wait for the sketch's version; SensorFault when nothing valid answers."""
        self._loop = asyncio.get_running_loop()
        try:
            self._open()
        except (serial.SerialException, OSError) as e:
            raise SensorFault(f"cannot open the FSR Arduino on {self.port}: {e}; check the USB cable") from e
        try:
            async with self.clock.timeout(self.version_timeout_s):
                await self._version_seen.wait()
        except TimeoutError:
            await self.stop()
            raise SensorFault(
                f"no dishbot_fsr sketch answered on {self.port} within {self.version_timeout_s:.1f} s; "
                "flash drivers/fsr/arduino/dishbot_fsr.ino and check the baud rate"
            ) from None
        self._watchdog = self._loop.create_task(self._watch())
        self._log.info("fsr_started", version=self.firmware_version)

    async def stop(self) -> None:
        for task in (self._reconnect, self._watchdog):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._reconnect = self._watchdog = None
        self._close()

    async def __aenter__(self) -> FsrReader:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.stop()

    # ------------------------------------------------------------------------------------------ ForceSensor

    def latest(self) -> ForceReading | None:
        return self._latest

    def holding(self) -> bool:
        return self._holding

    # ------------------------------------------------------------------------------------- for the daemon

    def set_carrying(self, carrying: bool) -> None:
        """Say whether a mug should be in the gripper; a release while carrying is reported as a drop."""
        self._carrying = carrying
        self._dropped = False

    @property
    def dropped(self) -> bool:
        """True once the force fell below the release level while carrying (until ``set_carrying``)."""
        return self._dropped

    def check(self) -> None:
        """Raise SensorFault when the sensor is unplugged or has sent no valid sample lately."""
        if self._lost:
            raise SensorFault(f"the FSR Arduino on {self.port} is unplugged; reconnecting")
        age = self.clock.monotonic() - self._latest.t if self._latest is not None else None
        if age is None or age > self.stale_after_s:
            seen = "no sample yet" if age is None else f"the last one is {age:.2f} s old"
            raise SensorFault(f"no valid FSR sample from {self.port} ({seen}); check the Arduino")

    def take_sample(self, sample: protocol.Sample) -> None:
        """A sample handed over without its line (``drivers.sim.FsrSimulator.tap_samples``): the reader
        ends as it would have after reading the line, valid as every simulated sample's is."""
        self._sample(sample)

    # ------------------------------------------------------------------------------------------ internals

    def _open(self) -> None:
        ser = self._open_serial(self.port, self.baudrate)
        ser.reset_input_buffer()
        ser.write(protocol.VERSION_QUERY)
        self._serial = ser
        self._buf.clear()
        assert self._loop is not None
        self._loop.add_reader(ser.fileno(), self._on_readable)

    def _close(self) -> None:
        ser, self._serial = self._serial, None
        if ser is None:
            return
        if self._loop is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(ser.fileno())
        with contextlib.suppress(serial.SerialException, OSError):
            ser.close()

    def _on_readable(self) -> None:
        ser = self._serial
        if ser is None:
            return
        try:
            data = ser.read(ser.in_waiting or 1)
            if not data:
                raise serial.SerialException("device reports readiness to read but returned no data")
        except (serial.SerialException, OSError) as e:
            self._unplugged(e)
            return
        self._feed(data)

    def _feed(self, data: bytes) -> None:
        self._buf += data
        while True:
            end = self._buf.find(b"\n")
            if end < 0:
                if len(self._buf) > protocol.MAX_LINE:
                    self.counters.bad_lines += 1
                    self._buf.clear()
                return
            line = bytes(self._buf[:end])
            del self._buf[: end + 1]
            self._line(line)

    def _line(self, line: bytes) -> None:
        start = line.rfind(b"$")
        if start > 0:  # the tail of a torn line precedes this one: count it, keep the good part
            self.counters.bad_lines += 1
            line = line[start:]
        parsed = protocol.parse_line(line) if len(line) <= protocol.MAX_LINE else None
        if parsed is None:
            if line.strip():
                self.counters.bad_lines += 1
            return
        if isinstance(parsed, protocol.Version):
            self.firmware_version = parsed.version
            self._version_seen.set()
            return
        self._sample(parsed)

    def _sample(self, sample: protocol.Sample) -> None:
        now = self.clock.monotonic()
        if self._last_seq is not None:
            gap = (sample.seq - self._last_seq - 1) % protocol.SEQ_MODULO
            self.counters.lost_samples += gap
        self._last_seq = sample.seq
        self.counters.samples += 1
        force = protocol.force_from_raw(sample.raw, gain=self.gain)
        self._window.append(force)
        filtered = statistics.median_low(self._window)
        if abs(force - filtered) > self.spike_n:
            self.counters.spikes += 1
        self._latest = ForceReading(t=now, force_n=filtered, raw=sample.raw, seq=sample.seq)
        self._debounce(filtered, now)
        if self._lost or self._stale:
            self._lost = self._stale = False
            self._log.info("fsr_restored")
            self._emit("fsr_restored")

    def _debounce(self, force: float, now: float) -> None:
        crossing = force < self.release_n if self._holding else force >= self.threshold_n
        if not crossing:
            self._pending_since = None
            return
        if self._pending_since is None:
            self._pending_since = now
        if now - self._pending_since < self.debounce_s:
            return
        self._pending_since = None
        self._holding = not self._holding
        self._log.debug("fsr_holding", holding=self._holding, force_n=force)
        if not self._holding and self._carrying and not self._dropped:
            self._dropped = True
            self._log.warning("mug_dropped", force_n=force)
            self._emit("mug_dropped", force_n=force)

    def _unplugged(self, cause: BaseException) -> None:
        self._close()
        if not self._lost:
            self._lost = True
            self._log.warning("fsr_lost", error=str(cause))
            self._emit("fsr_lost", error=str(cause))
        if self._reconnect is None or self._reconnect.done():
            assert self._loop is not None
            self._reconnect = self._loop.create_task(self._reconnect_loop())

    async def _reconnect_loop(self) -> None:
        while self._serial is None:
            await self.clock.sleep(self.reconnect_period_s)
            try:
                self._open()
            except (serial.SerialException, OSError) as e:
                self._log.debug("fsr_reconnect_failed", error=str(e))
                continue
            self.counters.reconnects += 1

    async def _watch(self) -> None:
        """Report once when the stream goes quiet while the port is still open."""
        while True:
            await self.clock.sleep(self.stale_after_s / 2)
            latest = self._latest
            quiet = latest is None or self.clock.monotonic() - latest.t > self.stale_after_s
            if quiet and not self._stale and not self._lost:
                self._stale = True
                self._log.warning("fsr_stale", stale_after_s=self.stale_after_s)
                self._emit("fsr_stale")

    def _emit(self, kind: str, **detail: object) -> None:
        if self._on_event is not None:
            self._on_event(DeviceEvent(kind, "fsr", self.clock.monotonic(), {"port": self.port, **detail}))
