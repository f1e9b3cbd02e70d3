"""The Dynamixel bus: the one place that talks to dynamixel-sdk. Blocking; confine it to one thread.

The SDK opens the port, sets the baud rate and runs single-servo transactions and sync writes. Reading the
whole chain is done here instead, with this package's codec: dynamixel-sdk 4.1's GroupBulkRead is broken on
Protocol 1.0 and GroupSyncRead drops each servo's status error byte, which would hide an overload. Waiting
for those answers sleeps in ``select`` rather than spinning, so the bus thread leaves the GIL to the event
loop. Timeouts and corrupt packets are retried a bounded number of times with per-servo counters; a
servo's fault bits become a :class:`ServoFault`; a servo that only answers with corrupt packets, or whose
recent answers are corrupt more often than ``corrupt_rate_max`` allows, a :class:`BusCorrupt`; a vanished
adapter is closed, reopened once and, when that fails, reported as :class:`BusLost` (once: while it stays
lost every access fails at once, so the daemon faults within a control tick, not after a round of waits).

The bus's own waits (for a status packet, a rebooting servo, a re-enumerating adapter) are waits on the
device, made through ``DynamixelBus.waits`` (``DeviceWaits``): in wall-clock time like dynamixel-sdk's packet
timeouts by default; on a simulated clock ``ServoChain`` makes them pass in simulated time, so a servo that
is silent for a moment is bridged by the retries as on the robot. Event times come from the ``Clock``.
"""

from __future__ import annotations

import collections
import contextlib
import select
import struct
import termios
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Protocol, TypeVar

import serial
import structlog
from dynamixel_sdk import PacketHandler, PortHandler

from drivers.dynamixel import faults
from drivers.dynamixel import protocol as p
from drivers.dynamixel.config import BusConfig
from drivers.dynamixel.tables import MODELS_BY_NUMBER, ModelSpec, model, volts_from_ticks
from drivers.errors import BusLost, ServoFault
from drivers.interfaces import Clock
from drivers.serial_port import OpenSerial, SerialPort

log = structlog.get_logger("drivers.dynamixel")

# What a vanished adapter raises from inside pyserial (termios.error is not an OSError).
_PORT_ERRORS = (serial.SerialException, OSError, termios.error)

_COMM_SUCCESS = 0
_COMM_RX_TIMEOUT = -3001
_COMM_RX_CORRUPT = -3002
_COMM_PORT_BUSY = -1000

T = TypeVar("T")

# A Protocol 1.0 state block (``_reading``): position, speed and load (little-endian 16 bits), voltage and
# temperature (a byte each).
_STATE_1: Final = struct.Struct("<HHHBB")


class ChainMismatch(ServoFault):
    """The servos found on the bus are not the configured ones; torque was not enabled."""

    def __init__(self, message: str, *, problems: tuple[str, ...]) -> None:
        super().__init__(message)
        self.problems = problems


class BusTimeout(ServoFault):
    """A servo did not answer (or only with corrupt packets) after every retry."""


class BusCorrupt(BusTimeout):
    """A servo's answers arrive garbled: every retry was corrupt, or more of its recent answers were corrupt
    than the bus's ``corrupt_rate_max`` allows (reason ``bus_corrupt``)."""


# The reason a fault event gives for each fault name (the first name that has one wins).
FAULT_REASONS: Final = {
    "overload": "overload",
    "overheating": "overheat",
    "input_voltage": "voltage",
    "no_status": "no_status",
    "bus_corrupt": "bus_corrupt",
    "electrical_shock": "electrical_shock",
    "motor_encoder": "motor_encoder",
}


def fault_reason(names: Sequence[str]) -> str:
    """The event ``reason`` of a fault carrying ``names`` (``overheating`` -> ``overheat``, ...)."""
    return next((FAULT_REASONS[n] for n in names if n in FAULT_REASONS), names[0] if names else "")


@dataclass(frozen=True, slots=True)
class DeviceEvent:
    """A fault appearing or clearing, as the daemon publishes it: ``kind`` is e.g. ``servo_fault``; ``t`` is
    the driver's clock (``Clock.monotonic``) when it happened."""

    kind: str
    device: str
    t: float
    detail: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class ServoReading:
    """One servo's present state in SI units, and the fault names its status carried."""

    servo_id: int
    position_rad: float
    velocity_rad_s: float
    load: float
    voltage_v: float
    temperature_c: int
    errors: tuple[str, ...] = ()


@dataclass(slots=True)
class ServoCounters:
    """Per-servo communication statistics since the bus was opened."""

    timeouts: int = 0
    corrupt: int = 0
    retries: int = 0
    faults: int = 0


EventSink = Callable[[DeviceEvent], None]


class DeviceWaits(Protocol):
    """How the bus waits on its device: the time its timeouts are measured in, a wait for bytes to read,
    and a pause (a rebooting servo, a re-enumerating adapter)."""

    def now(self) -> float:
        """Seconds on the clock the waits run on."""
        ...

    def readable(self, port: SerialPort, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for ``port`` to have bytes to read (or to read end-of-file); whether it
        has."""
        ...

    def sleep(self, seconds: float) -> None: ...


class WallWaits:
    """Waits on the wall clock, as on a serial adapter: ``select`` on the port, ``time.sleep``."""

    def now(self) -> float:
        return time.monotonic()

    def readable(self, port: SerialPort, timeout_s: float) -> bool:
        return bool(select.select([port.fileno()], [], [], max(0.0, timeout_s))[0])

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


class DynamixelBus:
    """A serial Dynamixel bus on dynamixel-sdk. Not thread-safe: one thread owns it.

    ``open_serial`` opens the port (default: dynamixel-sdk's own pyserial port on the device file); the
    simulated cell passes an in-process simulator's (``drivers.sim.inprocess``)."""

    def __init__(
        self,
        config: BusConfig,
        *,
        clock: Clock,
        retries: int = 2,
        read_timeout_s: float = 0.02,
        reopen_attempts: int = 1,
        corrupt_rate_max: float = 0.2,
        corrupt_window: int = 50,
        on_event: EventSink | None = None,
        open_serial: OpenSerial | None = None,
    ) -> None:
        """``reopen_attempts`` is how often a failing port is reopened when it first fails (later accesses
        try once, without waiting). A servo faults ``bus_corrupt`` when more than ``corrupt_rate_max`` of
        its last ``corrupt_window`` answers were corrupt."""
        self.config = config
        self.clock = clock
        self._open_serial = open_serial
        self.retries = retries
        self.read_timeout_s = read_timeout_s
        self.reopen_attempts = reopen_attempts
        self.corrupt_rate_max = corrupt_rate_max
        self.corrupt_window = corrupt_window
        self._recent: dict[int, collections.deque[bool]] = {}  # per servo: was each recent answer corrupt
        self._recent_corrupt: dict[int, int] = {}  # per servo: how many of those were (kept as they change)
        self._on_event = on_event
        self._port: Any = None
        self._packets: Any = PacketHandler(float(config.protocol))
        self.models: dict[int, ModelSpec] = {}
        self.counters: dict[int, ServoCounters] = {}
        # The state read of a list of servos, by that list: its instruction packet and the answers' data
        # lengths (the control loop reads the same few lists tens of thousands of times a job); forgotten
        # whenever a model is registered or moves to another id.
        self._blocks: dict[tuple[int, ...], tuple[bytes, dict[int, int]]] = {}
        # Each servo's last fault-free state block and the reading made of it: a servo at rest answers the
        # same bytes again (forgotten with the blocks, when a model changes).
        self._readings: dict[int, tuple[bytes, ServoReading]] = {}
        self._faulted: dict[int, tuple[str, ...]] = {}
        self._lost = False
        self._log = log.bind(port=config.port)
        # The open port's ``answers_at_once`` (None: it has none) and the port it was looked up on.
        self._probed: object = None
        self._probe: Callable[[], bool] | None = None
        # How waits on the device pass; the owner of the bus may swap it between transactions.
        self.waits: DeviceWaits = WallWaits()

    # ------------------------------------------------------------------------------------------ lifecycle

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        """Open the port at the configured baud rate; BusLost names the port when it cannot."""
        port = (
            PortHandler(self.config.port)
            if self._open_serial is None
            else _OpenedPortHandler(self.config.port, self._open_serial)
        )
        try:
            opened = port.openPort() and port.setBaudRate(self.config.baudrate)
        except (serial.SerialException, OSError) as e:
            raise BusLost(
                f"cannot open servo bus {self.config.port}: {e}; check the USB cable and the udev rule",
                port=self.config.port,
            ) from e
        if not opened:
            raise BusLost(
                f"cannot open servo bus {self.config.port} at {self.config.baudrate} bps",
                port=self.config.port,
            )
        self._port = port
        self._log.info("bus_open", baudrate=self.config.baudrate, protocol=self.config.protocol)

    def close(self) -> None:
        if self._port is None:
            return
        with contextlib.suppress(serial.SerialException, OSError):
            self._port.closePort()
        self._port = None
        self._log.info("bus_closed")

    def __enter__(self) -> DynamixelBus:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ chain

    def register(self, servo_id: int, model_name: str) -> None:
        """Tell the bus which model sits at an id (``verify`` does this after checking)."""
        self.models[servo_id] = model(model_name)
        self.counters.setdefault(servo_id, ServoCounters())
        self._blocks.clear()
        self._readings.clear()

    def ping(self, servo_id: int, *, attempts: int = 1) -> int | None:
        """The model number of the servo at ``servo_id``, or None when nothing answers.

        Fault bits in the answer are ignored here: a servo in overload still tells what it is.
        """
        protocol = self.config.protocol
        for _ in range(attempts):
            got = self._exchange(p.ping(protocol, servo_id), {servo_id: 0 if protocol == 1 else 3})
            if servo_id not in got:
                continue
            if protocol == 2:
                return p.from_le(got[servo_id].data[:2])
            model_reply = self._exchange(p.read(1, servo_id, 0, 2), {servo_id: 2})
            if servo_id in model_reply:
                return p.from_le(model_reply[servo_id].data)
        return None

    def scan(self, ids: Iterable[int] = range(p.MAX_ID + 1)) -> dict[int, int]:
        """Every id in ``ids`` that answers a ping, with its model number."""
        found = {}
        for servo_id in ids:
            number = self.ping(servo_id)
            if number is not None:
                found[servo_id] = number
        return found

    def verify(self, expected: Sequence[tuple[int, str]]) -> None:
        """Check every configured id answers with the configured model; one ChainMismatch lists all problems.

        Nothing is written to the servos, so the torque stays off when this fails.
        """
        problems: list[str] = []
        for servo_id, model_name in expected:
            want = model(model_name)
            number = self.ping(servo_id, attempts=1 + self.retries)
            if number is None:
                problems.append(f"servo {servo_id} ({model_name}) does not answer")
            elif number != want.number:
                found = MODELS_BY_NUMBER.get(number)
                name = found.name if found else f"unknown model {number}"
                problems.append(f"servo {servo_id} is a {name}, configured as {model_name}")
        if problems:
            raise ChainMismatch(
                f"servo chain on {self.config.port} does not match the config: "
                + "; ".join(problems)
                + ". Fix the ids with `dishbot servo scan` / `dishbot servo set-id`; torque was not enabled",
                problems=tuple(problems),
            )
        for servo_id, model_name in expected:
            self.register(servo_id, model_name)

    # ------------------------------------------------------------------------------------------ registers

    def read_register(self, servo_id: int, name: str, *, check: bool = True) -> int:
        """A named register's value; with ``check=False`` fault bits in the answer do not raise."""
        spec = self._model(servo_id)
        reg = spec.reg(name)
        packet = p.read(self.config.protocol, servo_id, reg.address, reg.size)
        data = self._transact(servo_id, packet, expect_data=reg.size, check=check)
        return p.from_le(data, signed=reg.signed)

    def write_register(self, servo_id: int, name: str, value: int, *, check: bool = True) -> None:
        """Write a named register and wait for the acknowledgement (``check`` as in ``read_register``)."""
        spec = self._model(servo_id)
        reg = spec.reg(name)
        packet = p.write(self.config.protocol, servo_id, reg.address, p.le(value, reg.size))
        self._transact(servo_id, packet, check=check)

    def set_id(self, servo_id: int, new_id: int) -> None:
        """Move a servo to another id (EEPROM; torque is turned off first) and check it answers there."""
        protocol = self.config.protocol
        reg = self._model(servo_id).reg("id")
        self.write_register(servo_id, "torque_enable", 0, check=False)
        # The acknowledgement may come from either id depending on the firmware.
        self._exchange(p.write(protocol, servo_id, reg.address, bytes((new_id,))), {servo_id: 0, new_id: 0})
        if self.ping(new_id, attempts=1 + self.retries) is None:
            raise BusTimeout(
                f"servo {servo_id} did not answer at its new id {new_id} on {self.config.port}",
                servo_id=servo_id,
            )
        self.models[new_id] = self.models.pop(servo_id)
        self._blocks.clear()
        self._readings.clear()

    def set_baud(self, servo_id: int, code: int, baudrate: int) -> None:
        """Switch a servo's baud rate register to ``code``, follow it with the port, check it answers."""
        protocol = self.config.protocol
        reg = self._model(servo_id).reg("baud_rate")
        self.write_register(servo_id, "torque_enable", 0, check=False)
        self._exchange(p.write(protocol, servo_id, reg.address, bytes((code,))), {servo_id: 0})
        self._io(lambda: self._port.setBaudRate(baudrate))
        if self.ping(servo_id, attempts=1 + self.retries) is None:
            raise BusTimeout(
                f"servo {servo_id} did not answer at {baudrate} bps on {self.config.port}", servo_id=servo_id
            )

    def reboot(self, servo_id: int, *, settle_s: float = 0.1) -> None:
        """Protocol 2.0 reboot (clears a hardware error shutdown); waits for the servo to come back."""
        result, _error = self._io(lambda: self._packets.reboot(self._port, servo_id))
        if result != _COMM_SUCCESS:
            raise BusTimeout(
                f"servo {servo_id} did not acknowledge the reboot on {self.config.port}", servo_id=servo_id
            )
        self.waits.sleep(settle_s)

    def answers_at_once(self) -> bool:
        """Whether the open port's device answers everything written to it before the write returns, and
        withholds nothing now (an in-process simulator with no silent, dropping or garbling servo and its
        cable plugged in): then a transaction never waits on the device. False on a real port."""
        ser = getattr(self._port, "ser", None)
        if ser is not self._probed:  # asked of every transaction: the probe is looked up once per port
            self._probed = ser
            probe = getattr(ser, "answers_at_once", None)
            self._probe = probe if callable(probe) else None
        return self._probe is not None and bool(self._probe())

    # ------------------------------------------------------------------------------------------ hot path

    def write_goals(self, goals: Mapping[int, tuple[float, float]]) -> None:
        """Goal positions (rad) and speeds (rad/s) of several servos in one sync write; no status comes back.

        Callers check software limits first (see ``DynamixelArm``); ticks are clamped to the servo range.
        """
        if not goals:
            return
        first = self._model(next(iter(goals)))
        address, length = first.goal_block
        param = bytearray()
        for servo_id, (position, speed) in goals.items():
            spec = self._model(servo_id)
            speed_ticks, pos_ticks = spec.speed_ticks_from_rad_s(speed), spec.ticks_from_rad(position)
            half = length // 2
            block = p.le(pos_ticks, half) + p.le(speed_ticks, half)
            if self.config.protocol == 2:  # 2.0: profile velocity (112) comes before goal position (116)
                block = p.le(speed_ticks, half) + p.le(pos_ticks, half)
            param += bytes((servo_id,)) + block
        result = self._io(
            lambda: self._packets.syncWriteTxOnly(self._port, address, length, list(param), len(param))
        )
        if result != _COMM_SUCCESS:
            raise BusLost(f"sync write failed on {self.config.port} (result {result})", port=self.config.port)

    def read_states(self, servo_ids: Sequence[int], *, check: bool = True) -> dict[int, ServoReading]:
        """Present position, speed, load, voltage and temperature of every listed servo, in one request.

        Protocol 1.0 uses a bulk read, 2.0 a sync read, both parsed here so every status error byte is seen.
        Missing or corrupt answers are retried ``retries`` times; a shutdown fault raises ServoFault (with
        ``check=False`` it is only reported and its name left in the reading's ``errors``).
        """
        counters = self.counters
        corrupt_before = [counters[i].corrupt if i in counters else 0 for i in servo_ids]
        statuses = self._read_block(servo_ids)
        for attempt in range(1 + self.retries):
            if attempt:
                statuses.update(self._read_block([i for i in servo_ids if i not in statuses]))
            still = [i for i in servo_ids if i not in statuses] if len(statuses) < len(servo_ids) else ()
            if not still:
                break
            for servo_id in still:
                self._counters(servo_id).retries += 1
            self._log.debug("read_retry", attempt=attempt + 1, missing=still)
        else:
            missing = [i for i in servo_ids if i not in statuses]
            before = dict(zip(servo_ids, corrupt_before, strict=True))
            garbled = [i for i in missing if self._counters(i).corrupt > before[i]]
            if garbled:
                self._raise_corrupt(garbled)
            # A daisy chain stalls behind a silent servo: blame those that miss a ping too, else the first
            # that did not answer (the ones after it only waited for it).
            silent = [i for i in missing if self.ping(i) is None] or missing[:1]
            for servo_id in silent:
                self._mark_fault(servo_id, ("no_status",))
            raise BusTimeout(
                f"servo(s) {', '.join(map(str, silent))} did not answer on {self.config.port} after "
                f"{1 + self.retries} tries; check the cable and power of the chain",
                servo_id=silent[0],
                bits=("no_status",),
            )
        readings = {i: self._reading(statuses[i], check=check) for i in servo_ids}
        self._check_corruption(servo_ids)
        return readings

    def reset_link_stats(self) -> None:
        """Forget the recent answers the corruption rate is judged on (after the cause was dealt with)."""
        self._recent.clear()
        self._recent_corrupt.clear()

    # ------------------------------------------------------------------------------------------ internals

    def _model(self, servo_id: int) -> ModelSpec:
        try:
            return self.models[servo_id]
        except KeyError:
            raise ServoFault(
                f"servo {servo_id} is not registered on {self.config.port}; verify the chain first",
                servo_id=servo_id,
            ) from None

    def _counters(self, servo_id: int) -> ServoCounters:
        counters = self.counters.get(servo_id)
        if counters is None:
            counters = self.counters[servo_id] = ServoCounters()
        return counters

    def _read_block(self, servo_ids: Sequence[int]) -> dict[int, p.Status]:
        if not servo_ids:
            return {}
        key = tuple(servo_ids)
        block = self._blocks.get(key)
        if block is None:
            block = self._blocks[key] = self._state_read(key)
        packet, expected = block
        return self._exchange(packet, expected)

    def _state_read(self, servo_ids: tuple[int, ...]) -> tuple[bytes, dict[int, int]]:
        """The instruction reading the state block of ``servo_ids`` and each answer's data length."""
        specs = [self._model(i) for i in servo_ids]
        address, length = specs[0].state_block
        if self.config.protocol == 1:
            packet = p.bulk_read_1(
                [(i, s.state_block[0], s.state_block[1]) for i, s in zip(servo_ids, specs, strict=True)]
            )
        else:
            packet = p.sync_read_2(address, length, servo_ids)
        return packet, {i: s.state_block[1] for i, s in zip(servo_ids, specs, strict=True)}

    def _exchange(self, packet: bytes, expected: Mapping[int, int]) -> dict[int, p.Status]:
        """Send one instruction and collect the statuses of ``expected`` (id -> data length) until timeout."""
        got: dict[int, p.Status] = {}
        short: dict[int, int] = {}  # error bytes of answers that came without their data
        framer = p.Framer(self.config.protocol)
        timeout = self.read_timeout_s + len(expected) * 0.002

        waits = self.waits

        def io() -> None:
            port = self._port
            port.clearPort()
            port.writePort(packet)
            ser = port.ser
            deadline = waits.now() + timeout
            while len(got) < len(expected):
                remaining = deadline - waits.now()
                if remaining <= 0:
                    if not ser.in_waiting:  # a host scheduled late may find the answer already read in
                        return
                elif not waits.readable(ser, remaining):
                    return
                data = ser.read(ser.in_waiting or 1)
                if not data:
                    raise serial.SerialException("device reports readiness to read but returned no data")
                for frame in framer.feed(data):
                    status = p.as_status(self.config.protocol, frame)
                    if status is None or status.servo_id not in expected or status.servo_id in got:
                        continue
                    if len(status.data) != expected[status.servo_id]:
                        self._counters(status.servo_id).corrupt += 1
                        if status.error:
                            short[status.servo_id] = status.error
                        continue
                    got[status.servo_id] = status

        self._io(io)
        if len(got) == len(expected):  # every servo answered: nothing to count but the answers
            for servo_id in expected:
                self._note_answer(servo_id, corrupt=False)
            return got
        for servo_id in expected:
            if servo_id in got:
                self._note_answer(servo_id, corrupt=False)
            elif framer.corrupt or servo_id in short:
                self._note_answer(servo_id, corrupt=True)
        for servo_id, error in short.items():
            if servo_id not in got:
                self._check_error(servo_id, error)  # a shutdown fault must not hide behind a short answer
        if framer.corrupt:
            for servo_id in expected:
                if servo_id not in got:
                    self._counters(servo_id).corrupt += 1
        for servo_id in expected:
            if servo_id not in got and not framer.corrupt:
                self._counters(servo_id).timeouts += 1
        return got

    def _transact(self, servo_id: int, packet: bytes, *, expect_data: int = 0, check: bool = True) -> bytes:
        """One instruction to one servo with retries; its status data, after checking the error byte."""
        corrupt_before = self._counters(servo_id).corrupt
        for attempt in range(1 + self.retries):
            got = self._exchange(packet, {servo_id: expect_data})
            if servo_id in got:
                status = got[servo_id]
                if check:
                    self._check_error(servo_id, status.error)
                    self._check_corruption([servo_id])
                return status.data
            self._counters(servo_id).retries += 1
            self._log.debug("transaction_retry", servo_id=servo_id, attempt=attempt + 1)
        if self._counters(servo_id).corrupt > corrupt_before:
            self._raise_corrupt([servo_id])
        self._mark_fault(servo_id, ("no_status",))
        raise BusTimeout(
            f"servo {servo_id} did not answer on {self.config.port} after {1 + self.retries} tries; "
            "check its cable and power",
            servo_id=servo_id,
            bits=("no_status",),
        )

    def _note_answer(self, servo_id: int, *, corrupt: bool) -> None:
        window = self._recent.get(servo_id)
        if window is None:
            window = self._recent[servo_id] = collections.deque(maxlen=self.corrupt_window)
            self._recent_corrupt[servo_id] = 0
        count = self._recent_corrupt[servo_id]
        if window and len(window) == window.maxlen and window[0]:
            count -= 1  # the oldest answer leaves the window
        window.append(corrupt)
        self._recent_corrupt[servo_id] = count + corrupt if window.maxlen else 0

    def _check_corruption(self, servo_ids: Iterable[int]) -> None:
        """BusCorrupt when more of a servo's recent answers were corrupt than ``corrupt_rate_max`` allows."""
        over = []
        for servo_id in servo_ids:
            if self._recent_corrupt.get(servo_id, 0) > self.corrupt_rate_max * self.corrupt_window:
                over.append(servo_id)
            elif self._faulted.get(servo_id) == ("bus_corrupt",):
                self._mark_clear(servo_id)  # back under the threshold
        if not over:
            return
        for servo_id in over:
            self._mark_fault(servo_id, ("bus_corrupt",))
        counts = ", ".join(f"servo {i}: {sum(self._recent[i])}" for i in over)
        raise BusCorrupt(
            f"corrupt answers on {self.config.port} passed {self.corrupt_rate_max:.0%} of the last "
            f"{self.corrupt_window} ({counts}); check the cable, its connectors and the supply",
            servo_id=over[0],
            bits=("bus_corrupt",),
        )

    def _raise_corrupt(self, servo_ids: Sequence[int]) -> None:
        for servo_id in servo_ids:
            self._mark_fault(servo_id, ("bus_corrupt",))
        raise BusCorrupt(
            f"servo(s) {', '.join(map(str, servo_ids))} answered only with corrupt packets on "
            f"{self.config.port} after {1 + self.retries} tries; check the cable, its connectors and the "
            "supply",
            servo_id=servo_ids[0],
            bits=("bus_corrupt",),
        )

    def _reading(self, status: p.Status, *, check: bool = True) -> ServoReading:
        servo_id = status.servo_id
        data = status.data
        clean = not status.error and servo_id not in self._faulted
        if clean:
            last = self._readings.get(servo_id)
            if last is not None and last[0] == data:
                return last[1]  # the same bytes as last time, nothing to report: the same reading
        spec = self._model(servo_id)
        if self.config.protocol == 1:  # 36: position, 38: speed, 40: load, 42: voltage, 43: temperature
            position, speed, load, volts, temp = _STATE_1.unpack_from(data)
        else:  # 126: load/current, 128: velocity, 132: position, 144: voltage, 146: temperature
            load = p.from_le(data[0:2], signed=True)
            speed = p.from_le(data[2:6], signed=True)
            position = p.from_le(data[6:10], signed=True)
            volts, temp = p.from_le(data[18:20]), data[20]
        errors: tuple[str, ...] = ()
        if status.error or servo_id in self._faulted:
            values = {"overheating": float(temp), "input_voltage": volts_from_ticks(volts)}
            errors = self._check_error(servo_id, status.error, raise_shutdown=check, values=values)
        reading = ServoReading(
            servo_id=servo_id,
            position_rad=spec.rad_from_ticks(position),
            velocity_rad_s=spec.velocity_from_ticks(speed),
            load=spec.load_from_ticks(load),
            voltage_v=volts_from_ticks(volts),
            temperature_c=temp,
            errors=errors,
        )
        if clean:
            self._readings[servo_id] = (data, reading)
        return reading

    def _check_error(
        self,
        servo_id: int,
        error: int,
        *,
        raise_shutdown: bool = True,
        values: Mapping[str, float] | None = None,
    ) -> tuple[str, ...]:
        """Decode a status error byte; raise ServoFault on a shutdown fault (``raise_shutdown=False``: only
        report it), else return the names."""
        if not error and servo_id not in self._faulted:
            return ()  # the common answer: nothing to report, nothing to clear
        names = faults.error_names(self.config.protocol, error)
        if "alert" in names:
            status = self._read_hardware_error(servo_id)
            names = tuple(n for n in names if n != "alert") + faults.hardware_error_names(status)
        shutdown = tuple(n for n in names if n in faults.SHUTDOWN_FAULTS)
        if shutdown:
            self._mark_fault(servo_id, shutdown, values)
            if not raise_shutdown:
                return names
            raise ServoFault(
                f"servo {servo_id} on {self.config.port} reports {', '.join(shutdown)}; "
                "its torque is off until the fault is cleared",
                servo_id=servo_id,
                bits=shutdown,
            )
        if self._faulted.get(servo_id) != ("bus_corrupt",):  # that clears with the rate, not one answer
            self._mark_clear(servo_id)
        return names

    def _read_hardware_error(self, servo_id: int) -> int:
        reg = self._model(servo_id).reg("hardware_error_status")
        got = self._exchange(p.read(2, servo_id, reg.address, reg.size), {servo_id: reg.size})
        return got[servo_id].data[0] if servo_id in got else 0

    def _mark_fault(
        self, servo_id: int, names: tuple[str, ...], values: Mapping[str, float] | None = None
    ) -> None:
        """Report a servo's fault once (until it changes or clears); ``values`` are the present readings
        behind some names (temperature for ``overheating``), given as the event's ``value``."""
        self._counters(servo_id).faults += 1
        if self._faulted.get(servo_id) == names:
            return
        self._faulted[servo_id] = names
        reason = fault_reason(names)
        extra: dict[str, object] = {}
        value = next((values[n] for n in names if values and n in values), None)
        if value is not None:
            extra["value"] = value
        self._log.warning("servo_fault", servo_id=servo_id, faults=list(names), reason=reason)
        self.emit(
            "servo_fault",
            f"servo/{servo_id}",
            servo_id=servo_id,
            servo=servo_id,
            reason=reason,
            faults=list(names),
            **extra,
        )

    def _mark_clear(self, servo_id: int) -> None:
        if self._faulted.pop(servo_id, None) is None:
            return
        self._log.info("servo_recovered", servo_id=servo_id)
        self.emit("servo_recovered", f"servo/{servo_id}", servo_id=servo_id)

    def clear_fault(self, servo_id: int) -> None:
        """Forget a servo's fault after a recovery step, logging that it cleared."""
        self._mark_clear(servo_id)

    def faulted(self) -> dict[int, tuple[str, ...]]:
        return dict(self._faulted)

    def emit(self, kind: str, device: str, **detail: object) -> None:
        """Report an event to the listener (recovery policies above the bus use it too)."""
        if self._on_event is not None:
            self._on_event(DeviceEvent(kind, device, self.clock.monotonic(), dict(detail)))

    def _io(self, call: Callable[[], T]) -> T:
        """Run port I/O; an unplugged adapter is closed, reopened once per attempt, and else BusLost."""
        if self._port is None:
            self._reopen(RuntimeError("port closed"))
        try:
            result = call()
        except _PORT_ERRORS as e:
            # pyserial raises inside the SDK and leaves the port marked in use: start from a fresh port.
            self._reopen(e)
            try:
                result = call()
            except _PORT_ERRORS as again:
                self._drop_port()
                raise BusLost(
                    f"servo bus {self.config.port} failed again after reopening: {again}",
                    port=self.config.port,
                ) from again
        if self._lost:
            self._lost = False
            self._log.info("bus_restored")
            self.emit("bus_restored", "bus", port=self.config.port)
        return result

    def _drop_port(self) -> None:
        if self._port is not None:
            self._port.is_using = False
            with contextlib.suppress(*_PORT_ERRORS):
                self._port.closePort()
        self._port = None

    @property
    def lost(self) -> bool:
        """Whether the adapter is gone (since the last access failed, until one succeeds)."""
        return self._lost

    def _reopen(self, cause: BaseException) -> None:
        """Reopen a failed port: ``reopen_attempts`` times when it first fails, once (without waiting) while
        it stays lost, so every access to a pulled adapter fails at once."""
        first = not self._lost
        if first:
            self._lost = True
            self._log.warning("bus_lost", error=str(cause))
            self.emit("bus_lost", "bus", port=self.config.port, error=str(cause))
        self._drop_port()
        last: BaseException = cause
        attempts = max(1, self.reopen_attempts) if first else 1
        for attempt in range(attempts):
            try:
                self.open()
                return
            except BusLost as e:
                last = e
                if attempt + 1 < attempts:
                    self.waits.sleep(0.05)
        raise BusLost(
            f"servo bus {self.config.port} is gone ({last}); plug the USB adapter back in to reconnect",
            port=self.config.port,
        ) from cause


class _OpenedPortHandler(PortHandler):  # type: ignore[misc]  # dynamixel-sdk is untyped
    """dynamixel-sdk's port handler on a port that ``open_serial`` opens (the SDK's own ``setupPort``
    hard-codes pyserial on a device file); everything else is the SDK's."""

    def __init__(self, port_name: str, open_serial: OpenSerial) -> None:
        super().__init__(port_name)
        self._open_serial = open_serial

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 (the SDK's name, overridden)
        if self.is_open:  # type: ignore[has-type]  # set by the SDK's untyped __init__
            self.closePort()
        self.ser = self._open_serial(self.port_name, self.baudrate)
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True
