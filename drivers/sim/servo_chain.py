"""A Dynamixel daisy chain on a pseudo-terminal, speaking Protocol 1.0 or 2.0 byte for byte.

Each simulated servo owns a control table (the model's registers at their real addresses and sizes) and
answers instruction packets the way the e-Manual describes: status packets with checksum or CRC and byte
stuffing, the return delay, error bits, a torque limit that drops to 0 on a 1.0 overload, Hardware Error
Status and reboot on 2.0, the moving flag and the present load. A :class:`~drivers.sim.plant.ServoPlant`
supplies where the servos are. Fault hooks make a servo overload, overheat or see its input voltage leave the
limits (the present temperature or voltage register and the error bits as the firmware sets them, with the
torque cut where the Shutdown register says so), fall silent or send corrupt bytes (a number of packets, or a
seeded fraction of all of them), and unplug the whole adapter.

On a pseudo-terminal (``start()``) the chain answers from its own thread; in-process
(``start_in_process(clock)``) it answers on the host's thread as the host writes, with no wire time, and
tells the host whether it withholds anything now (``InProcessPort.answers_at_once``: a silent servo, a lost
or garbled answer), so a host on a simulated clock can let its timeouts pass in simulated time then
(``drivers.dynamixel.ServoChain``). A servo's present registers are synced from the plant when read, and
left as they are when the plant reports what they were synced from.
"""

from __future__ import annotations

import functools
import random
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, Self

import structlog

from description.thesis import JOINT_SERVOS
from drivers.dynamixel import faults
from drivers.dynamixel import protocol as p
from drivers.dynamixel.tables import ModelSpec, baud_code, baud_from_code, model
from drivers.interfaces import Clock
from drivers.sim.device import SimulatedDevice
from drivers.sim.plant import FirstOrderPlant, PlantStopped, ServoPlant
from drivers.sim.pty_link import PtyLink

log = structlog.get_logger("drivers.sim.servo_chain")

_FACTORY_RETURN_DELAY = 250  # ticks of 2 µs: the factory setting of both protocols


@dataclass(slots=True)
class SimServo:
    """One simulated servo: its control table and its injected faults."""

    spec: ModelSpec
    table: bytearray
    silent: bool = False
    drop_next: int = 0
    corrupt_next: int = 0
    overload_repeats: int = 0  # how many more times the servo trips when it is next driven
    registered: list[tuple[int, bytes]] = field(default_factory=list)
    hardware_error: int = 0  # 2.0 Hardware Error Status bits; 1.0 latched error bits
    corrupt_every: int = 0  # every nth status packet is corrupt (0: none); see ``corrupt_every``
    answers: int = 0  # status packets sent, for ``corrupt_every``
    # A load the servo cannot hold (``keep_overloaded``): it trips again whenever it is driven. Heat and the
    # supply are registers (present temperature and voltage against the servo's limits), not conditions.
    conditions: set[str] = field(default_factory=set)
    # What the present registers were last synced from: the plant's (position, velocity, load) and the
    # error bits; None after anything else wrote the table (see ``ServoChainSimulator._sync_from_plant``).
    synced: tuple[float, float, float, int] | None = None
    # What the synced registers hold: the present position, speed and load ticks and the error bits (a new
    # plant state that rounds to the same ticks leaves the table, and the status packets answered from it,
    # as they are); None after anything else wrote the table.
    registers: tuple[int, int, int, int] | None = None
    live: int | None = None  # the error bits of the present conditions; None: to be worked out again
    # Status packets answered since the table last changed, by (address, length, error bits): an idle
    # servo's answer is the same bytes again.
    packets: dict[tuple[int, int, int], bytes] = field(default_factory=dict)
    layout: dict[str, tuple[int, int, bool]] = field(default_factory=dict)

    # Where the registers synced from the plant sit (``ServoChainSimulator._sync_from_plant``): (address,
    # size, signed) of the present position, speed (1.0) or velocity (2.0), load (or current), the goal
    # position, and the moving flag's and (2.0) Hardware Error Status's addresses (-1: none).
    present: tuple[tuple[int, int, bool], ...] = ()
    moving_at: int = -1
    hardware_error_at: int = -1
    torque_at: int = -1  # Torque Enable's address (one byte on both protocols)
    id_at: int = -1  # the id's address (one byte on both protocols)
    limit_at: int = -1  # 1.0: Torque Limit's address (two bytes, unsigned); -1 on 2.0

    def __post_init__(self) -> None:
        # (address, size, signed) by name: the simulator looks registers up several times per packet.
        self.layout = {name: (r.address, r.size, r.signed) for name, r in self.spec.registers.items()}
        layout = self.layout
        speed = "present_speed" if self.spec.protocol == 1 else "present_velocity"
        load = "present_load" if "present_load" in layout else "present_current"
        self.present = tuple(layout[n] for n in ("present_position", speed, load, "goal_position"))
        self.moving_at = layout["moving"][0]
        self.torque_at = layout["torque_enable"][0]
        self.id_at = layout["id"][0]
        if "torque_limit" in layout:
            self.limit_at = layout["torque_limit"][0]
        if self.spec.protocol == 2:
            self.hardware_error_at = layout["hardware_error_status"][0]

    @property
    def servo_id(self) -> int:
        return self.table[self.id_at]  # one byte on both protocols

    def torque_enable(self) -> int:
        """``get("torque_enable")`` without the lookup by name (asked several times per write)."""
        return self.table[self.torque_at]

    def torque_limit(self) -> int:
        """``get("torque_limit")`` (1.0) without the lookup by name."""
        at = self.limit_at
        return self.table[at] | self.table[at + 1] << 8

    def goal_position(self) -> int:
        """``get("goal_position")`` without the lookup by name (asked twice per goal written)."""
        address, size, signed = self.present[3]
        return int.from_bytes(self.table[address : address + size], "little", signed=signed)

    def get(self, name: str) -> int:
        try:
            address, size, signed = self.layout[name]
        except KeyError:
            self.spec.reg(name)  # says which name is unknown
            raise
        if size == 1 and not signed:
            return self.table[address]
        return int.from_bytes(self.table[address : address + size], "little", signed=signed)

    def set(self, name: str, value: int) -> None:
        try:
            address, size, _signed = self.layout[name]
        except KeyError:
            self.spec.reg(name)
            raise
        self.table[address : address + size] = _le(value, size)
        self.registers = None
        if self.packets:
            self.packets.clear()
        if name in _CONDITION_REGISTERS:
            self.live = None


# The registers the live error conditions (supply voltage, heat) are read from.
_CONDITION_REGISTERS: Final = frozenset(
    {"present_voltage", "present_temperature", "min_voltage", "max_voltage", "temperature_limit"}
)


class ServoChainSimulator(SimulatedDevice):
    """A chain of simulated servos on a pty (a context manager) or in-process; open :attr:`device_path`.

    ``wire_timing`` makes answers on a pty take as long as their bytes would at ``baudrate`` (plus the return
    delay), so cycle rates measured over the simulator are those of a real 1 Mbps bus rather than of a pty.
    ``plant`` is what moves behind the servos (default: a ``FirstOrderPlant`` on the wall clock).
    """

    def __init__(
        self,
        servos: Sequence[tuple[int, str]],
        *,
        protocol: p.Protocol = 1,
        baudrate: int = 1_000_000,
        plant: ServoPlant | None = None,
        return_delay_ticks: int = _FACTORY_RETURN_DELAY,
        wire_timing: bool = True,
        name: str = "ttyDXL",
    ) -> None:
        self.protocol: p.Protocol = protocol
        self.baudrate = baudrate
        self.plant: ServoPlant = plant if plant is not None else FirstOrderPlant(clock=_wall)
        self._own_plant = plant is None
        self.wire_timing = wire_timing
        self._servos: list[SimServo] = []
        for servo_id, model_name in servos:
            spec = model(model_name)
            if spec.protocol != protocol:
                raise ValueError(f"{model_name} speaks Protocol {spec.protocol}.0, the chain {protocol}.0")
            self._servos.append(self._new_servo(spec, servo_id, baudrate, return_delay_ticks))
        super().__init__(name, thread_name="servo-chain-sim")
        self._lock = threading.Lock()
        self._silent_all = False
        self._garbage = b""
        self._framer = p.Framer(protocol)
        self._corrupt_rate = 0.0
        self._corrupt_only: int | None = None
        self._rng = random.Random(0)
        # The servos that hear the host at its baud rate, by id, for the host's baud rate (None: not worked
        # out since an id or a baud rate changed).
        self._heard: tuple[int | None, list[SimServo], dict[int, SimServo]] | None = None
        self.packets_seen = 0
        self.packets_corrupted = 0
        self._plant_stopped = False  # the plant raised PlantStopped: no servo answers anything from then on
        # On a pty, when the line is free for the next answer (wall clock): the instruction heard, or the
        # previous answer's last byte gone (see ``_wire_delay``).
        self._line_free_at = 0.0

    @staticmethod
    def _new_servo(spec: ModelSpec, servo_id: int, baudrate: int, return_delay: int) -> SimServo:
        servo = SimServo(spec, bytearray(spec.control_table_size))
        servo.set("model_number", spec.number)
        servo.set("firmware", 41 if spec.protocol == 2 else 36)
        servo.set("id", servo_id)
        servo.set("baud_rate", baud_code(spec.protocol, baudrate))
        servo.set("return_delay", return_delay)
        servo.set("temperature_limit", 70 if spec.protocol == 1 else 80)
        # The factory voltage limits in 0.1 V: 1.0 AX 6-14 V, MX 6-16 V; 2.0 X series 9.5-16 V.
        if spec.protocol == 1:
            servo.set("min_voltage", 60)
            servo.set("max_voltage", 140 if spec.name.startswith("AX") else 160)
        else:
            servo.set("min_voltage", 95)
            servo.set("max_voltage", 160)
        if spec.protocol == 1:
            servo.set("cw_angle_limit", 0)
            servo.set("ccw_angle_limit", spec.max_tick)
            servo.set("max_torque", spec.default_torque_limit)
            servo.set("torque_limit", spec.default_torque_limit)
            servo.set("status_return_level", 2)
            servo.set("alarm_led", 0x24)
            servo.set("shutdown", 0x24)
        else:
            servo.set("operating_mode", 3)
            servo.set("pwm_limit", spec.default_torque_limit)
            servo.set("goal_pwm", spec.default_torque_limit)
            servo.set("max_position", spec.max_tick)
            servo.set("min_position", 0)
            servo.set("status_return_level", 2)
            servo.set("shutdown", 0x34)
        servo.set("present_voltage", 120)
        servo.set("present_temperature", 32)
        servo.set("present_position", spec.center_tick)
        servo.set("goal_position", spec.center_tick)
        return servo

    # ------------------------------------------------------------------------------------------ lifecycle

    def start_in_process(self, clock: Clock) -> Self:
        """In-process on ``clock``; the default plant then moves in that clock's time too."""
        if self._own_plant:
            self.plant = FirstOrderPlant(clock=clock.monotonic)
        return super().start_in_process(clock)

    def _prepare(self) -> None:
        self._framer = p.Framer(self.protocol)
        for servo in self._servos:
            self._sync_from_plant(servo)

    def _unplugged(self) -> None:
        with self._lock:
            self._framer = p.Framer(self.protocol)

    # ------------------------------------------------------------------------------------------ fault hooks

    @property
    def servo_ids(self) -> tuple[int, ...]:
        """The ids of the simulated servos, in chain order."""
        return tuple(s.servo_id for s in self._servos)

    def servo(self, servo_id: int) -> SimServo:
        for servo in self._servos:
            if servo.servo_id == servo_id:
                return servo
        raise KeyError(f"no simulated servo with id {servo_id}")

    def overload(self, servo_id: int, *, now: bool = True, repeats: int = 0) -> None:
        """Trip the servo's overload protection (now, unless ``now=False``) and ``repeats`` more times, each
        time a goal position reaches it while it is powered, as a gripper squeezing a jam would."""
        with self._lock:
            servo = self.servo(servo_id)
            if now:
                self._trip(servo)
            servo.overload_repeats = repeats

    def keep_overloaded(self, servo_id: int, *, on: bool = True) -> None:
        """Trip the overload now and (``on``) every time the servo is driven or its fault cleared, until
        called with ``on=False``: a load the servo cannot hold (a jam) that lasts."""
        with self._lock:
            servo = self.servo(servo_id)
            if on:
                servo.conditions.add("overload")
                self._trip(servo)
            else:
                servo.conditions.discard("overload")

    def overheat(self, servo_id: int, *, on: bool = True) -> None:
        """Raise the present temperature 5 °C above the servo's Temperature Limit (``on``), which sets the
        overheating error bit and, as the factory Shutdown register asks, cuts the torque; with ``on=False``
        the servo cools back to 32 °C, and the latched bit clears the way the servo allows (1.0: rewriting
        the torque limit, 2.0: a reboot)."""
        limit = self.servo(servo_id).get("temperature_limit")
        self.set_present_temperature(servo_id, limit + 5 if on else 32)

    def brown_out(self, servo_id: int, *, on: bool = True) -> None:
        """Drop the present voltage 1 V below the servo's Min Voltage Limit (``on``): the input voltage
        error bit is set (1.0: in every status while it lasts; 2.0: in Hardware Error Status, with the alert
        flag, until a reboot). The factory Shutdown register does not cut the torque for it. With
        ``on=False`` the supply is back at 12 V."""
        low = self.servo(servo_id).get("min_voltage") / 10.0 - 1.0
        self.set_present_voltage(servo_id, max(0.0, low) if on else 12.0)

    def corrupt_fraction(self, rate: float, *, seed: int = 0, servo_id: int | None = None) -> None:
        """Flip a bit in ``rate`` (0-1) of all status packets (of one servo, or the whole chain), chosen by a
        random generator seeded with ``seed``: a noisy line. ``rate`` 0 stops it."""
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"corrupt rate {rate} is outside 0..1")
        with self._lock:
            self._corrupt_rate = rate
            self._corrupt_only = servo_id
            self._rng = random.Random(seed)

    def silence(self, servo_id: int | None = None, *, on: bool = True) -> None:
        """Stop one servo (or, with None, the whole chain) from answering, as with a loose cable."""
        with self._lock:
            if servo_id is None:
                self._silent_all = on
            else:
                self.servo(servo_id).silent = on

    def drop(self, servo_id: int, *, packets: int = 1) -> None:
        """Swallow the servo's next ``packets`` answers: a transient 'no status packet'."""
        with self._lock:
            self.servo(servo_id).drop_next = packets

    def corrupt(self, servo_id: int, *, packets: int = 1) -> None:
        """Flip a bit in the next ``packets`` status packets of a servo, so their checksum fails."""
        with self._lock:
            self.servo(servo_id).corrupt_next = packets

    def corrupt_every(self, servo_id: int, nth: int) -> None:
        """From now on corrupt every ``nth`` status packet of a servo (0 stops it): a marginal cable."""
        with self._lock:
            servo = self.servo(servo_id)
            servo.corrupt_every, servo.answers = nth, 0

    def set_present_voltage(self, servo_id: int, volts: float) -> None:
        """The servo's supply now reads ``volts``. Outside its Min/Max Voltage Limit it raises the input
        voltage error (1.0: in every status while it lasts; 2.0: latched in Hardware Error Status until a
        reboot finds it gone), and shuts down when its Shutdown register says so."""
        with self._lock:
            servo = self.servo(servo_id)
            servo.set("present_voltage", round(volts * 10))
            self._apply_conditions(servo)

    def set_present_temperature(self, servo_id: int, celsius: int) -> None:
        """The servo's internal temperature now reads ``celsius``; past its Temperature Limit it raises the
        overheating error and (with the factory Shutdown setting) cuts its torque, as the e-Manual says:
        1.0 drops Torque Limit to 0, 2.0 clears Torque Enable until a reboot."""
        with self._lock:
            servo = self.servo(servo_id)
            servo.set("present_temperature", celsius)
            self._apply_conditions(servo)

    def inject_garbage(self, data: bytes) -> None:
        """Bytes sent to the host before the next answer, as electrical noise on the line would be."""
        with self._lock:
            self._garbage += data

    # ------------------------------------------------------------------------------------------ serving

    def _serve(self) -> None:
        assert isinstance(self._link, PtyLink)
        link = self._link
        was_plugged = True
        while not self._stop.is_set():
            data = link.read(0.02)
            if link.plugged != was_plugged:
                was_plugged = link.plugged
                self._unplugged()
            if data:
                self._line_free_at = time.monotonic()  # the answers' wire time counts from here
                self._received(data)

    def _received(self, data: bytes) -> None:
        with self._lock:
            frames = list(self._framer.feed(data))
        for frame in frames:
            self.packets_seen += 1
            if self._plant_stopped:
                continue
            try:
                self._handle(frame)
            except PlantStopped as e:  # the servos' physical side is gone: silent, as without power
                self._plant_stopped = True  # the frames after this one are skipped above: said once
                log.error("sim_servos_silent", reason=str(e))
            except Exception:  # the simulator must keep serving whatever the host sends
                log.exception("sim_packet_failed", servo_id=frame.servo_id, code=frame.code)

    def _answers_at_once(self) -> bool:
        """No servo withholds or garbles an answer now (silent, dropping, corrupting), no noise waits on the
        line and the adapter is plugged in: every servo the host addresses has answered before its write
        returns (in-process)."""
        link = self._link
        if link is None or not link.plugged or self._silent_all or self._corrupt_rate > 0.0 or self._garbage:
            return False
        return not any(s.silent or s.drop_next or s.corrupt_next or s.corrupt_every for s in self._servos)

    def _listening(self) -> tuple[list[SimServo], dict[int, SimServo]]:
        """Servos whose baud rate matches the host's (the others hear only noise), and the same by id."""
        if self._silent_all:
            return [], {}
        host = self._link.host_baudrate() if self._link is not None else None
        heard = self._heard
        if heard is None or heard[0] != host:
            servos = (
                list(self._servos)
                if host is None
                else [s for s in self._servos if _baud(self.protocol, s.get("baud_rate")) == host]
            )
            heard = self._heard = (host, servos, {s.servo_id: s for s in servos})
        return heard[1], heard[2]

    def _handle(self, frame: p.Frame) -> None:
        link = self._link
        if link is None:
            return
        with self._lock:
            servos, by_id = self._listening()
            replies = self._dispatch(frame, servos, by_id)
            garbage, self._garbage = self._garbage, b""
        # In-process every answer is there at once: the bytes go out in one write, as they would follow
        # each other on the wire. On a pty each waits for its own wire time.
        batch = self.in_process
        out = bytearray(garbage)
        if garbage and not batch:
            link.write(garbage)
        for servo, packet in replies:
            dropped = servo.drop_next > 0
            servo.drop_next -= dropped
            if servo.silent or dropped:
                # Daisy-chained reads wait for the previous answer; a silent servo stalls the rest.
                if frame.code in (p.BULK_READ, p.SYNC_READ):
                    break
                continue
            servo.answers += 1
            every = servo.corrupt_every and servo.answers % servo.corrupt_every == 0
            if servo.corrupt_next or every or (self._corrupt_rate > 0.0 and self._corrupts(servo)):
                if servo.corrupt_next and not every:
                    servo.corrupt_next -= 1
                self.packets_corrupted += 1
                packet = packet[:-2] + bytes((packet[-2] ^ 0x10,)) + packet[-1:]
            if batch:
                out += packet
            else:
                self._wire_delay(servo, len(packet))
                link.write(packet)
        if batch and out:
            link.write(bytes(out))

    def _corrupts(self, servo: SimServo) -> bool:
        """Whether the random line noise hits this status packet."""
        if self._corrupt_rate <= 0.0 or self._corrupt_only not in (None, servo.servo_id):
            return False
        return self._rng.random() < self._corrupt_rate

    def _wire_delay(self, servo: SimServo, nbytes: int) -> None:
        """On a pty, hold an answer until a real bus would have carried it: its return delay and its bytes
        after the line was free (the instruction heard, or the answer before it sent). It sleeps (never
        spins: the driver may share this interpreter) only until then, so a thread that a loaded machine
        ran late sends at once rather than adding each answer's wire time to its lateness (a chain's bulk
        read is five answers). In-process the answer is there at once: it takes no simulated time."""
        if not self.wire_timing or self.in_process:
            return
        self._line_free_at += servo.get("return_delay") * 2e-6 + nbytes * 10 / self.baudrate
        wait = self._line_free_at - time.monotonic()
        if wait > 0:
            time.sleep(wait)

    def _dispatch(
        self, frame: p.Frame, servos: list[SimServo], by_id: dict[int, SimServo] | None = None
    ) -> list[tuple[SimServo, bytes]]:
        if by_id is None:
            by_id = {s.servo_id: s for s in servos}
        code, params = frame.code, frame.params
        if frame.servo_id == p.BROADCAST_ID:
            if code == p.SYNC_WRITE:
                self._sync_write(params, by_id)
            elif code == p.BULK_READ and self.protocol == 1:
                return self._bulk_read_1(params, by_id)
            elif code == p.BULK_READ:
                return self._bulk_read_2(params, by_id)
            elif code == p.SYNC_READ and self.protocol == 2:
                return self._sync_read_2(params, by_id)
            elif code == p.PING and self.protocol == 2:
                return [(s, self._status(s, 0, self._ping_data(s))) for s in sorted(servos, key=_id)]
            elif code in (p.WRITE, p.ACTION):
                for each in servos:
                    self._single(each, code, params)
            return []
        target = by_id.get(frame.servo_id)
        if target is None:
            return []
        return [(target, self._single(target, code, params))]

    def _single(self, servo: SimServo, code: int, params: bytes) -> bytes:
        if code == p.PING:
            return self._status(servo, 0, self._ping_data(servo))
        if code == p.READ:
            address, length = self._address_length(params)
            if address is None:
                return self._status(servo, self._instruction_error())
            return self._read(servo, address, length)
        if code in (p.WRITE, p.REG_WRITE):
            split = 1 if self.protocol == 1 else 2
            if len(params) <= split:
                return self._status(servo, self._instruction_error())
            address = p.from_le(params[:split])
            if code == p.REG_WRITE:
                servo.registered.append((address, params[split:]))
                return self._status(servo, 0)
            return self._status(servo, self._write(servo, address, params[split:]))
        if code == p.ACTION:
            error = 0
            for address, data in servo.registered:
                error |= self._write(servo, address, data)
            servo.registered.clear()
            return self._status(servo, error)
        if code == p.REBOOT:
            self._reboot(servo)
            return self._status(servo, 0)
        return self._status(servo, self._instruction_error())

    def _ping_data(self, servo: SimServo) -> bytes:
        if self.protocol == 1:
            return b""
        return p.le(servo.spec.number, 2) + bytes((servo.get("firmware"),))

    def _address_length(self, params: bytes) -> tuple[int | None, int]:
        if self.protocol == 1:
            return (params[0], params[1]) if len(params) == 2 else (None, 0)
        return (p.from_le(params[:2]), p.from_le(params[2:4])) if len(params) == 4 else (None, 0)

    def _instruction_error(self) -> int:
        return 0x40 if self.protocol == 1 else 2

    def _range_error(self) -> int:
        return 0x08 if self.protocol == 1 else 4

    def _error_byte(self, servo: SimServo) -> int:
        if self.protocol == 1:
            live = servo.live
            return servo.hardware_error | (self._live_conditions(servo) if live is None else live)
        return faults.ALERT_2 if servo.hardware_error else 0

    def _status(self, servo: SimServo, error: int, data: bytes = b"") -> bytes:
        return p.encode_status(self.protocol, servo.servo_id, error | self._error_byte(servo), data)

    def _read(self, servo: SimServo, address: int, length: int) -> bytes:
        if length == 0 or address + length > len(servo.table):
            return self._status(servo, self._range_error())
        self._sync_from_plant(servo)
        error = self._error_byte(servo)
        key = (address, length, error)
        packet = servo.packets.get(key)
        if packet is None:
            data = bytes(servo.table[address : address + length])
            packet = servo.packets[key] = p.encode_status(self.protocol, servo.servo_id, error, data)
        return packet

    def _sync_write(self, params: bytes, by_id: dict[int, SimServo]) -> None:
        head = 2 if self.protocol == 1 else 4
        if len(params) < head:
            return
        address, length = self._address_length(params[:head])
        if address is None or length == 0:
            return
        body = params[head:]
        for i in range(0, len(body) - length, length + 1):
            servo = by_id.get(body[i])
            if servo is not None:
                self._write(servo, address, body[i + 1 : i + 1 + length])

    def _bulk_read_1(self, params: bytes, by_id: dict[int, SimServo]) -> list[tuple[SimServo, bytes]]:
        replies = []
        for i in range(1, len(params) - 2, 3):
            length, servo_id, address = params[i], params[i + 1], params[i + 2]
            servo = by_id.get(servo_id)
            if servo is None:
                break
            replies.append((servo, self._read(servo, address, length)))
        return replies

    def _sync_read_2(self, params: bytes, by_id: dict[int, SimServo]) -> list[tuple[SimServo, bytes]]:
        if len(params) < 5:
            return []
        address, length = p.from_le(params[:2]), p.from_le(params[2:4])
        replies = []
        for servo_id in params[4:]:
            servo = by_id.get(servo_id)
            if servo is None:
                break
            replies.append((servo, self._read(servo, address, length)))
        return replies

    def _bulk_read_2(self, params: bytes, by_id: dict[int, SimServo]) -> list[tuple[SimServo, bytes]]:
        replies = []
        for i in range(0, len(params) - 4, 5):
            servo = by_id.get(params[i])
            if servo is None:
                break
            address, length = p.from_le(params[i + 1 : i + 3]), p.from_le(params[i + 3 : i + 5])
            replies.append((servo, self._read(servo, address, length)))
        return replies

    # ------------------------------------------------------------------------------------------ registers

    def _write(self, servo: SimServo, address: int, data: bytes) -> int:
        """Apply a write like the servo's firmware; the status error to answer with."""
        spec = servo.spec
        end = address + len(data)
        if end > len(servo.table):
            return self._range_error()
        span = _span(spec, address, len(data))
        if self.protocol == 2 and span.eeprom and servo.torque_enable():
            return 7  # access error: EEPROM is locked while the torque is on
        # What the write may change that matters after it (only looked at when it can change).
        before_torque = servo.torque_enable() if span.torque_enable else 0
        limp_before = self.protocol == 1 and span.torque_limit and servo.torque_limit() == 0
        checked = span.goal or span.id
        saved = bytes(servo.table[address:end]) if checked else b""  # all the write changes
        servo.table[address:end] = data
        servo.synced = servo.registers = None  # the host may have written over the present registers too
        if servo.packets:
            servo.packets.clear()
        if span.conditions:
            servo.live = None
        if span.hearing:
            self._heard = None
        if checked and (
            (span.goal and not 0 <= servo.goal_position() <= spec.max_tick)
            or (span.id and servo.get("id") > p.MAX_ID)
        ):
            servo.table[address:end] = saved
            return self._range_error()
        if self.protocol == 1 and span.torque_limit and servo.torque_limit() > 0:
            # Restoring the torque limit clears a latched shutdown on the 1.0 servos and powers them again;
            # a servo still too hot trips again at once (a lasting overload trips when next driven).
            # A shutdown for a live condition (heat that has passed) latches no bit but left the torque
            # limit at 0: powering it again is the same.
            latched = faults.bits_for(1, ("overload", "overheating"))
            if (servo.hardware_error & latched or limp_before) and servo.torque_enable():
                self.plant.set_torque(servo.servo_id, True)
            servo.hardware_error &= ~latched
            self._apply_conditions(servo)  # a cause still present (still too hot) shuts it down again
        if span.torque_enable:
            on = bool(servo.torque_enable())
            if on and (self.protocol == 2 and servo.hardware_error & servo.get("shutdown")):
                servo.set("torque_enable", 0)  # a 2.0 servo in shutdown refuses torque until rebooted
            elif on != bool(before_torque):
                self.plant.set_torque(servo.servo_id, on)
        limp = self.protocol == 1 and servo.torque_limit() == 0
        if span.motion and servo.torque_enable() and not limp:
            if (servo.overload_repeats or "overload" in servo.conditions) and span.goal:
                servo.overload_repeats = max(0, servo.overload_repeats - 1)
                self._trip(servo)
                return self._error_byte(servo) if self.protocol == 1 else 0
            speed_reg = "moving_speed" if self.protocol == 1 else "profile_velocity"
            speed_ticks = servo.get(speed_reg) or 1023
            self.plant.set_goal(
                servo.servo_id,
                spec.rad_from_ticks(servo.goal_position()),
                spec.velocity_from_ticks(speed_ticks & 0x3FF if self.protocol == 1 else speed_ticks),
            )
        return 0

    def _trip(self, servo: SimServo) -> None:
        """Overload shutdown: 1.0 drops the torque limit to 0 until it is rewritten, 2.0 clears Torque Enable
        and refuses it until a reboot."""
        self._raise_error(servo, "overload")
        log.info("sim_overload", servo_id=servo.servo_id)

    def _raise_error(self, servo: SimServo, name: str) -> None:
        """Set an error condition's bit; cut the torque when the Shutdown register names it (1.0: the torque
        limit drops to 0 until it is rewritten; 2.0: Torque Enable clears and stays refused until a
        reboot)."""
        bit = faults.bits_for(self.protocol, (name,))
        servo.hardware_error |= bit
        self._shut_down_for(servo, bit)

    def _shut_down_for(self, servo: SimServo, bits: int) -> None:
        """Cut the torque when the Shutdown register names one of ``bits`` (1.0: the torque limit drops to 0
        until it is rewritten; 2.0: Torque Enable clears and stays refused until a reboot)."""
        if not servo.get("shutdown") & bits:
            return
        if self.protocol == 1:
            servo.set("torque_limit", 0)
        else:
            servo.set("torque_enable", 0)
        self.plant.set_torque(servo.servo_id, False)

    def _reboot(self, servo: SimServo) -> None:
        servo.hardware_error = 0
        servo.set("torque_enable", 0)
        self.plant.set_torque(servo.servo_id, False)
        if self.protocol == 1:
            servo.set("torque_limit", servo.get("max_torque"))
        self._apply_conditions(servo)  # a cause still present is found again at boot

    def _live_conditions(self, servo: SimServo) -> int:
        """The error bits the present voltage and temperature raise against the servo's own limits."""
        if servo.live is None:
            servo.live = self._work_out_conditions(servo)
        return servo.live

    def _work_out_conditions(self, servo: SimServo) -> int:
        volts = servo.get("present_voltage")
        names = []
        if not servo.get("min_voltage") <= volts <= servo.get("max_voltage"):
            names.append("input_voltage")
        if servo.get("present_temperature") > servo.get("temperature_limit"):
            names.append("overheating")
        return faults.bits_for(self.protocol, tuple(names))

    def _apply_conditions(self, servo: SimServo) -> None:
        """Raise the errors of the present conditions (2.0 latches them) and shut the servo down for those
        its Shutdown register selects."""
        live = self._live_conditions(servo)
        if self.protocol == 2:
            servo.hardware_error |= live
            servo.set("hardware_error_status", servo.hardware_error)
        self._shut_down_for(servo, live)

    def _sync_from_plant(self, servo: SimServo) -> None:
        """Bring the present registers up to the plant's state. A servo whose plant state (and error bits)
        are what the table was last synced from, or round to the ticks it holds, with nothing written since,
        already reads right: the registers are not rewritten (a servo at rest, or read twice at one
        simulated instant), and the status packets answered from them stay cached."""
        position, velocity, load = self.plant.present(servo.servo_id)
        state = (position, velocity, load, servo.hardware_error)
        if servo.synced == state:
            return
        servo.synced = state
        spec = servo.spec
        present = spec.ticks_from_rad(position)
        registers = (present, spec.velocity_to_ticks(velocity), spec.load_to_ticks(load), state[3])
        if servo.registers == registers:
            return  # a servo at rest: the plant's state moved by less than a tick
        servo.registers = registers
        table = servo.table
        # The registers written in place (what ``SimServo.set`` would write, without its per-name lookups):
        # none of them is one the live conditions are read from. The position tick is clamped to the
        # servo's range, so it is its own register value and reads back as itself.
        (pa, ps, _), (sa, ss, _), (la, ls, _), (ga, gs, gsigned) = servo.present
        table[pa : pa + ps] = present.to_bytes(ps, "little")
        table[sa : sa + ss] = _le(registers[1], ss)
        table[la : la + ls] = _le(registers[2], ls)
        goal = int.from_bytes(table[ga : ga + gs], "little", signed=gsigned)
        table[servo.moving_at] = int(abs(goal - present) > 2)
        if servo.hardware_error_at >= 0:
            table[servo.hardware_error_at] = servo.hardware_error & 0xFF
        if servo.packets:
            servo.packets.clear()


def _le(value: int, size: int) -> bytes:
    """``value`` as a register of ``size`` bytes holds it (two's complement for a negative one)."""
    return (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


@dataclass(frozen=True, slots=True)
class _Span:
    """The registers a write of some bytes at some address touches, and what the simulator must do about
    it (worked out once per model, address and length: every write asks)."""

    names: frozenset[str]
    eeprom: bool  # an EEPROM register (locked while a 2.0 servo's torque is on)
    goal: bool  # the goal position (range-checked; moves the servo)
    id: bool  # the id (range-checked; changes who hears the host)
    conditions: bool  # a register the live error conditions are read from
    hearing: bool  # the id or the baud rate: which servos hear the host
    motion: bool  # the goal position or the speed: the plant is given a new goal
    torque_enable: bool  # Torque Enable (the plant's torque follows it)
    torque_limit: bool  # 1.0 Torque Limit (restoring it clears a latched shutdown)


_SPANS: dict[tuple[str, int, int], _Span] = {}


def _span(spec: ModelSpec, address: int, length: int) -> _Span:
    """The registers a write of ``length`` bytes at ``address`` touches (cached: a write asks every time)."""
    key = (spec.name, address, length)
    span = _SPANS.get(key)
    if span is None:
        names = frozenset(
            name
            for name, reg in spec.registers.items()
            if reg.address < address + length and address < reg.address + reg.size
        )
        span = _SPANS[key] = _Span(
            names=names,
            eeprom=any(spec.registers[n].eeprom for n in names),
            goal="goal_position" in names,
            id="id" in names,
            conditions=not _CONDITION_REGISTERS.isdisjoint(names),
            hearing="baud_rate" in names or "id" in names,
            motion=bool(names & {"goal_position", "moving_speed", "profile_velocity"}),
            torque_enable="torque_enable" in names,
            torque_limit="torque_limit" in names,
        )
    return span


@functools.cache
def _baud(protocol: p.Protocol, code: int) -> int | None:
    """The baud rate a servo's baud rate register selects (cached: it is asked for every packet)."""
    return baud_from_code(protocol, code)


def _id(servo: SimServo) -> int:
    return servo.servo_id


def _wall() -> float:
    """The default plant's clock: a chain on a pty answers in wall-clock time (``dishbot sim bus``)."""
    return time.monotonic()


def default_chain() -> tuple[tuple[int, str], ...]:
    """The thesis arm's chain: ids 1-6 in joint order (§3.2.1)."""
    return tuple((i, servo) for i, (_, servo) in enumerate(JOINT_SERVOS, start=1))
