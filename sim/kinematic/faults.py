"""The kinematic cell's device faults, failing the way the real drivers fail on the robot.

The kinematic cell has no serial devices, so its devices carry the faults themselves: each device call checks
the servos it would talk to and raises exactly what the Dynamixel bus driver raises for the same condition
(``ServoFault`` naming the shutdown bits, ``BusTimeout`` for a servo that does not answer after every retry,
``BusLost`` for an unplugged adapter), and it reports the same device events (``servo_fault``,
``servo_recovered``, ``bus_lost``, ``bus_restored``, ``fsr_stale``, ``fsr_lost``, ``fsr_restored``) to the
listeners, as the drivers do through ``Backend.on_event``. The force sensor's faults (silence, a drop to
zero, a spike, an unplugged Arduino) and the camera's (no frame, stale, bad frame, hang, at the observer)
live here too, for one place to inject them.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from drivers.dynamixel import BusTimeout, DeviceEvent
from drivers.dynamixel.faults import SHUTDOWN_FAULTS
from drivers.errors import BusLost, ServoFault
from drivers.interfaces import Clock

PORT = "sim"  # the kinematic cell's one bus, as messages name it
FSR_PORT = "sim-fsr"
ARM_SERVOS = (1, 2, 3, 4, 5)  # the thesis chain's joint servos (§3.2.1), as the configured default
GRIPPER_SERVO = 6
RETRIES = 2  # the configured bus retries: three tries in all
FSR_STALE_AFTER_S = 0.2  # as the FSR reader's default

Listener = Callable[[DeviceEvent], None]


@dataclass(slots=True)
class ServoCondition:
    """One simulated servo's injected state: latched error bits, lasting causes, silence."""

    latched: set[str] = field(default_factory=set)  # shutdown bits until cleared as the servo allows
    lasting: set[str] = field(default_factory=set)  # causes that hold until the fault ends
    silent: bool = False
    voltage_v: float = 12.0
    temperature_c: float = 32.0


class KinematicFaults:
    """Faults of the kinematic cell's devices, on ``clock``; ``servos`` are the chain's ids."""

    def __init__(self, clock: Clock, *, servos: Iterable[int] = (*ARM_SERVOS, GRIPPER_SERVO)) -> None:
        self.clock = clock
        self.servos: dict[int, ServoCondition] = {i: ServoCondition() for i in servos}
        self.bus_unplugged = False
        self._bus_lost_reported = False
        self._reported: dict[int, tuple[str, ...]] = {}
        self.corrupt_rate = 0.0
        self._corrupt_only: int | None = None
        self._rng = random.Random(0)
        self.corrupt_packets = 0
        self.retried = 0
        self.fsr_silent = False
        self.fsr_unplugged = False
        self.fsr_dropped = False
        self.fsr_spikes: list[float] = []
        self.fsr_spikes_seen = 0
        self._fsr_down: str | None = None  # the event reported for the sensor being away
        self._listeners: list[Listener] = []

    def on_event(self, listener: Listener) -> None:
        """Call ``listener`` with every fault and recovery, as the drivers report them (on the loop)."""
        self._listeners.append(listener)

    def emit(self, kind: str, device: str, **detail: object) -> None:
        event = DeviceEvent(kind, device, self.clock.monotonic(), dict(detail))
        for listener in self._listeners:
            listener(event)

    # --- servos -------------------------------------------------------------------------------------------

    def servo(self, servo_id: int) -> ServoCondition:
        try:
            return self.servos[servo_id]
        except KeyError:
            raise KeyError(f"no simulated servo with id {servo_id}") from None

    def trip(self, servo_id: int, name: str, *, lasting: bool = False) -> None:
        """Set a shutdown bit (``overload`` or ``overheating``); ``lasting``: its cause stays until
        :meth:`end`, so clearing the bit does not work meanwhile."""
        servo = self.servo(servo_id)
        servo.latched.add(name)
        if lasting:
            servo.lasting.add(name)
        if name == "overheating":
            servo.temperature_c = 75.0  # above the 70 °C limit of the 1.0 servos

    def brown_out(self, servo_id: int, *, on: bool = True) -> None:
        """The servo's input voltage leaves its limits (a warning bit; the torque stays on)."""
        servo = self.servo(servo_id)
        servo.voltage_v = 5.0 if on else 12.0
        (servo.lasting.add if on else servo.lasting.discard)("input_voltage")

    def end(self, servo_id: int, name: str) -> None:
        """The cause of a fault is gone; a latched bit still needs clearing as the servo allows."""
        servo = self.servo(servo_id)
        servo.lasting.discard(name)
        if name == "overheating":
            servo.temperature_c = 32.0

    def clear(self, servo_id: int, name: str) -> bool:
        """Clear a latched bit (rewriting the torque limit); False when its cause is still there."""
        servo = self.servo(servo_id)
        if name in servo.lasting:
            return False
        servo.latched.discard(name)
        return True

    def silence(self, servo_id: int, *, on: bool = True) -> None:
        self.servo(servo_id).silent = on

    def corrupt_fraction(self, rate: float, *, seed: int = 0, servo_id: int | None = None) -> None:
        """Corrupt ``rate`` of the status packets (of one servo, or all), by a generator seeded with
        ``seed``; a servo whose every try comes back corrupt did not answer, as on the bus."""
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"corrupt rate {rate} is outside 0..1")
        self.corrupt_rate = rate
        self._corrupt_only = servo_id
        self._rng = random.Random(seed)

    def unplug_bus(self, on: bool = True) -> None:
        self.bus_unplugged = on

    def check_servos(self, servo_ids: Iterable[int]) -> None:
        """One bus transaction with ``servo_ids``: raise what the Dynamixel bus raises, report its events."""
        ids = [i for i in servo_ids if i in self.servos]
        if self.bus_unplugged:
            if not self._bus_lost_reported:
                self._bus_lost_reported = True
                self.emit("bus_lost", "bus", port=PORT, error="the adapter was unplugged")
            raise BusLost(
                f"servo bus {PORT} is gone (the adapter was unplugged); plug the USB adapter back in to "
                "reconnect",
                port=PORT,
            )
        if self._bus_lost_reported:
            self._bus_lost_reported = False
            self.emit("bus_restored", "bus", port=PORT)
        missing = [i for i in ids if self.servos[i].silent or not self._answered(i)]
        if missing:
            silent = [i for i in missing if self.servos[i].silent] or missing
            for servo_id in silent:
                self._mark(servo_id, ("no_status",))
            raise BusTimeout(
                f"servo(s) {', '.join(map(str, silent))} did not answer on {PORT} after {1 + RETRIES} "
                "tries; check the cable and power of the chain",
                servo_id=silent[0],
                bits=("no_status",),
            )
        for servo_id in ids:
            shutdown = tuple(sorted(self.servos[servo_id].latched & SHUTDOWN_FAULTS))
            if shutdown:
                self._mark(servo_id, shutdown)
                raise ServoFault(
                    f"servo {servo_id} on {PORT} reports {', '.join(shutdown)}; its torque is off until "
                    "the fault is cleared",
                    servo_id=servo_id,
                    bits=shutdown,
                )
            self.mark_clear(servo_id)

    def shut_down(self, servo_id: int) -> bool:
        """Whether the servo's torque is off for a latched shutdown fault."""
        return bool(self.servos[servo_id].latched & SHUTDOWN_FAULTS) if servo_id in self.servos else False

    def mark_clear(self, servo_id: int) -> None:
        if self._reported.pop(servo_id, None) is not None:
            self.emit("servo_recovered", f"servo/{servo_id}", servo_id=servo_id)

    def _answered(self, servo_id: int) -> bool:
        """Whether one of the tries got an uncorrupted status packet (corrupt ones are retried)."""
        if self.corrupt_rate <= 0.0 or self._corrupt_only not in (None, servo_id):
            return True
        for attempt in range(1 + RETRIES):
            if self._rng.random() >= self.corrupt_rate:
                return True
            self.corrupt_packets += 1
            if attempt < RETRIES:
                self.retried += 1
        return False

    def _mark(self, servo_id: int, names: tuple[str, ...]) -> None:
        if self._reported.get(servo_id) == names:
            return
        self._reported[servo_id] = names
        self.emit("servo_fault", f"servo/{servo_id}", servo_id=servo_id, faults=list(names))

    # --- force sensor -------------------------------------------------------------------------------------

    def fsr_away(self, *, age_s: float) -> bool:
        """Whether the FSR sends nothing now (silent or unplugged); reports it once, as the reader does
        (``fsr_lost`` at once, ``fsr_stale`` once the last sample is older than the reader allows)."""
        if self.fsr_unplugged:
            if self._fsr_down != "fsr_lost":
                self._fsr_down = "fsr_lost"
                self.emit("fsr_lost", "fsr", port=FSR_PORT, error="the Arduino was unplugged")
            return True
        if self.fsr_silent:
            if self._fsr_down is None and age_s > FSR_STALE_AFTER_S:
                self._fsr_down = "fsr_stale"
                self.emit("fsr_stale", "fsr", port=FSR_PORT)
            return True
        if self._fsr_down is not None:
            self._fsr_down = None
            self.emit("fsr_restored", "fsr", port=FSR_PORT)
        return False


class KinematicHealth:
    """The kinematic cell's ``drivers.interfaces.DeviceHealth``: what its injected faults leave standing,
    asked before a start and cleared on reset as the servos allow (a latched bit whose cause is gone is
    cleared; a cause that lasts, a silent servo or an unplugged bus stands). Polling asks every servo once,
    as the chain's health check does, so a fault met while idle is found."""

    def __init__(self, faults: KinematicFaults, *, poll_period_s: float = 1.0) -> None:
        self._faults = faults
        self._period = poll_period_s

    @property
    def poll_period_s(self) -> float:
        return self._period

    async def poll(self) -> None:
        self._faults.check_servos(self._faults.servos)

    def problems(self) -> tuple[str, ...]:
        f = self._faults
        out = []
        if f.bus_unplugged:
            out.append(f"servo bus {PORT} is gone (the adapter was unplugged)")
        for servo_id, s in sorted(f.servos.items()):
            if s.silent:
                out.append(f"servo {servo_id} does not answer")
            for name in sorted(s.latched):
                out.append(f"servo {servo_id} reports {name}; reset to clear it")
        return tuple(out)

    async def clear(self) -> tuple[str, ...]:
        f = self._faults
        for servo_id, s in f.servos.items():
            for name in sorted(s.latched):
                if f.clear(servo_id, name):
                    f.mark_clear(servo_id)
        return tuple(p for p in self.problems() if "reset to clear" not in p) + tuple(
            f"servo {i} still has the cause of its {n} (it lasts)"
            for i, s in sorted(f.servos.items())
            for n in sorted(s.latched)
        )
