"""The servo chain's health: present voltage and temperature watched against configured limits, and the
check ``reset`` runs to clear what a servo can be cleared of.

``ChainHealth.poll`` reads every servo once (one bulk or sync read, error bytes included) and compares its
supply voltage and temperature with ``HealthLimits`` (``drivers.dynamixel.config``): near a limit is a
``servo_warning``, past it a ``servo_fault`` (reasons ``voltage`` and ``overheat``; the events name the
servo, the value and the limit), as is the input voltage error bit a servo raises against its own voltage
window. While any servo is past a limit the poll raises :class:`ServoHealthFault`. Leaving a level takes
the value back by a small hysteresis so a reading on a limit's edge does not flap.

``ChainHealth.clear`` is the device side of ``reset``: the bus reopened if it was lost, every servo asked
for its status and, when it reports a shutdown error, cleared as its protocol allows (the e-Manual's way:
Protocol 2.0 REBOOT, which clears Hardware Error Status and leaves the torque off; Protocol 1.0 Torque Limit
restored, which the shutdown dropped to 0, and the torque enabled again once the cause is gone), its torque
enabled again holding where it stands. What still stands comes back as one line per problem.
``ChainHealth.problems`` says what stands without touching the bus (``start`` asks it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final, Literal

import structlog

from drivers.dynamixel import faults
from drivers.dynamixel.bus import DynamixelBus, ServoReading
from drivers.dynamixel.chain import ServoChain
from drivers.dynamixel.config import HealthLimits as HealthLimits  # where the sims and tests find it
from drivers.dynamixel.tables import volts_from_ticks
from drivers.errors import BusLost, ServoFault

log = structlog.get_logger("drivers.dynamixel.health")

Level = Literal["warning", "fault"]
Reason = Literal["voltage", "overheat"]

# How far back inside a threshold a value must come before its level is left.
HYSTERESIS_C: Final = 2.0
HYSTERESIS_V: Final = 0.2


class ServoHealthFault(ServoFault):
    """A servo's supply voltage or temperature is past its configured limit, or it reports the input
    voltage error."""


@dataclass(frozen=True, slots=True)
class Finding:
    """One servo near or past one limit."""

    servo: int
    level: Level
    reason: Reason
    value: float
    limit: float
    error_bit: bool = False  # the servo raised its own error bit for it
    past: bool = (
        True  # the value itself is beyond ``limit`` (not so: held by the hysteresis, or a latched bit)
    )

    def describe(self) -> str:
        unit = "V" if self.reason == "voltage" else "°C"
        what = "supply voltage" if self.reason == "voltage" else "temperature"
        error = "the input voltage error" if self.reason == "voltage" else "overheating"
        reading = f"servo {self.servo} {what} {self.value:g} {unit}"
        if self.level == "warning":
            return f"{reading} is near its limit {self.limit:g} {unit}"
        if self.past:
            bit = f" (the servo reports {error})" if self.error_bit else ""
            return f"{reading} is past its limit {self.limit:g} {unit}{bit}"
        if self.error_bit:  # latched, or raised against the servo's own limit
            now = f"{what} now {self.value:g} {unit}, limit {self.limit:g} {unit}"
            return f"servo {self.servo} reports {error} ({now})"
        return f"{reading} is not yet back inside its limit {self.limit:g} {unit}"  # the hysteresis


@dataclass(frozen=True, slots=True)
class ServoLimits:
    """A servo's own limits (its control table's), behind its error bits."""

    voltage_min_v: float
    voltage_max_v: float
    temperature_c: float


def _level(excess_fault: float, excess_warn: float, before: Level | None, hysteresis: float) -> Level | None:
    """The level of a value ``excess_*`` beyond the fault and warning thresholds (positive: past it)."""
    if excess_fault > 0 or (before == "fault" and excess_fault > -hysteresis):
        return "fault"
    if excess_warn >= 0 or (before is not None and excess_warn > -hysteresis):
        return "warning"
    return None


def assess(
    reading: ServoReading,
    limits: HealthLimits,
    before: Mapping[Reason, Level] | None = None,
    *,
    servo_limits: ServoLimits | None = None,
) -> list[Finding]:
    """The findings for one servo's reading; ``before`` holds its levels at the last poll (hysteresis);
    ``servo_limits`` are the servo's own, named when only its error bit says so."""
    before = before or {}
    found: list[Finding] = []
    t = float(reading.temperature_c)
    level = _level(
        t - limits.temperature_limit_c, t - limits.temperature_warn_c, before.get("overheat"), HYSTERESIS_C
    )
    if "overheating" in reading.errors:
        level = "fault"
    if level is not None:
        limit = limits.temperature_limit_c if level == "fault" else limits.temperature_warn_c
        bit = "overheating" in reading.errors
        if bit and t <= limit and servo_limits is not None:  # only the servo's own limit says so
            limit = servo_limits.temperature_c
        past = t > limit if level == "fault" else t >= limit
        found.append(Finding(reading.servo_id, level, "overheat", t, limit, bit, past))
    v = reading.voltage_v
    lo, hi, margin = limits.voltage_min_v, limits.voltage_max_v, limits.voltage_warn_margin_v
    low = v < (lo + hi) / 2
    level = _level(
        (lo - v) if low else (v - hi),
        (lo + margin - v) if low else (v - hi + margin),
        before.get("voltage"),
        HYSTERESIS_V,
    )
    bit = "input_voltage" in reading.errors
    if level == "fault" or bit:
        limit = lo if low else hi
        if level != "fault" and servo_limits is not None:  # only the servo's own window says so
            limit = servo_limits.voltage_min_v if low else servo_limits.voltage_max_v
        past = v < limit if low else v > limit
        found.append(Finding(reading.servo_id, "fault", "voltage", round(v, 2), limit, bit, past))
    elif level == "warning":
        limit = lo + margin if low else hi - margin
        found.append(Finding(reading.servo_id, "warning", "voltage", round(v, 2), limit))
    return found


class ChainHealth:
    """Watches and clears the servos of one chain; implements ``drivers.interfaces.DeviceHealth`` with the
    FSR left to its reader."""

    def __init__(self, chain: ServoChain, limits: HealthLimits | None = None) -> None:
        self._chain = chain
        self.limits = limits or HealthLimits()
        self._ids = tuple(i for i, _ in chain.expected)
        self._levels: dict[int, dict[Reason, Level]] = {}

    @property
    def poll_period_s(self) -> float:
        return self.limits.poll_period_s

    async def poll(self) -> None:
        """Read every servo's voltage and temperature; report what changed; ServoHealthFault while any servo
        is past a limit (a lost bus or a silent servo raises as any bus access does)."""
        standing = await self._chain.call(self._poll)
        if standing:
            first = standing[0]
            raise ServoHealthFault(
                "; ".join(f.describe() for f in standing),
                servo_id=first.servo,
                bits=tuple(dict.fromkeys(f.reason for f in standing)),
            )

    def problems(self) -> tuple[str, ...]:
        """What stands against a start, from what the bus and the last poll saw (no bus traffic)."""
        bus = self._chain.bus
        if bus.lost:
            return (f"servo bus {self._chain.config.port} is lost; plug the USB adapter back in and reset",)
        faulted = bus.faulted()
        out = [
            f"servo {i} reports {', '.join(names)}; reset to clear it" for i, names in sorted(faulted.items())
        ]
        for servo, levels in sorted(self._levels.copy().items()):  # a copy: the bus thread replaces entries
            for reason, level in levels.items():
                if level == "fault" and servo not in faulted:
                    out.append(f"servo {servo} is past its {reason} limit; reset once it is back inside")
        return tuple(out)

    async def clear(self) -> tuple[str, ...]:
        """Reset's device check: reopen a lost bus, clear every servo that can be cleared, re-enable its
        torque; one line per problem that still stands (empty: every servo is fine)."""
        return await self._chain.call(self._clear)

    # ------------------------------------------------------------------------------------------ bus thread

    def _poll(self, bus: DynamixelBus) -> list[Finding]:
        readings = bus.read_states(self._ids, check=False)
        standing: list[Finding] = []
        for servo_id in self._ids:
            findings = self._judge(bus, readings[servo_id])
            standing += [f for f in findings if f.level == "fault"]
        return standing

    def _judge(self, bus: DynamixelBus, reading: ServoReading, *, afresh: bool = False) -> list[Finding]:
        """Assess one reading against the last levels (``afresh``: without their hysteresis, as reset
        does), emitting an event for each level entered."""
        servo_id = reading.servo_id
        before = self._levels.get(servo_id, {})
        bits = {"input_voltage", "overheating"} & set(reading.errors)
        own = self._servo_limits(bus, servo_id) if bits else None
        findings = assess(reading, self.limits, {} if afresh else before, servo_limits=own)
        now: dict[Reason, Level] = {f.reason: f.level for f in findings}
        for f in findings:
            if before.get(f.reason) == f.level:
                continue
            detail = {
                "servo_id": servo_id,
                "servo": servo_id,
                "reason": f.reason,
                "value": f.value,
                "limit": f.limit,
                "error_bit": f.error_bit,
            }
            if f.level == "warning":
                log.warning("servo_warning", **detail)
                bus.emit("servo_warning", f"servo/{servo_id}", **detail)
            elif not self._bus_reported(bus, servo_id, f.reason):
                log.error("servo_fault", **detail)
                bus.emit("servo_fault", f"servo/{servo_id}", **detail)
        for reason in before.keys() - now.keys():
            log.info("servo_health_ok", servo_id=servo_id, reason=reason)
            bus.emit("servo_health_ok", f"servo/{servo_id}", servo_id=servo_id, servo=servo_id, reason=reason)
        self._levels[servo_id] = now
        return findings

    @staticmethod
    def _bus_reported(bus: DynamixelBus, servo_id: int, reason: Reason) -> bool:
        """Whether the bus already reported this as a servo fault (a shutdown error bit): one event per
        cause."""
        name = "overheating" if reason == "overheat" else "input_voltage"
        return name in bus.faulted().get(servo_id, ())

    @staticmethod
    def _servo_limits(bus: DynamixelBus, servo_id: int) -> ServoLimits | None:
        try:
            return ServoLimits(
                volts_from_ticks(bus.read_register(servo_id, "min_voltage", check=False)),
                volts_from_ticks(bus.read_register(servo_id, "max_voltage", check=False)),
                float(bus.read_register(servo_id, "temperature_limit", check=False)),
            )
        except ServoFault:
            return None

    def _clear(self, bus: DynamixelBus) -> tuple[str, ...]:
        bus.reset_link_stats()
        problems: list[str] = []
        for servo_id, model_name in self._chain.expected:
            try:
                problem = self._clear_servo(bus, servo_id)
            except BusLost as e:
                return (str(e),)
            except ServoFault as e:  # silent, garbled, or refusing the torque
                problem = f"{model_name} servo {servo_id}: {e}"
            if problem is not None:
                problems.append(problem)
        return tuple(problems)

    def _clear_servo(self, bus: DynamixelBus, servo_id: int) -> str | None:
        """Clear one servo as its protocol allows; the problem that stands, or None."""
        protocol = self._chain.config.protocol
        reading = bus.read_states([servo_id], check=False)[servo_id]
        shutdown = _shutdown(reading.errors)
        if protocol == 2 and "input_voltage" in reading.errors:
            shutdown += ("input_voltage",)  # latched in Hardware Error Status until a reboot
        if shutdown:
            how = "a reboot" if protocol == 2 else "restoring its torque limit"
            log.info("servo_clearing", servo_id=servo_id, faults=list(shutdown), how=how)
            if protocol == 2:
                bus.reboot(servo_id)
            else:
                bus.write_register(servo_id, "torque_enable", 0, check=False)
                full = bus.read_register(servo_id, "max_torque", check=False)
                bus.write_register(servo_id, "torque_limit", full, check=False)
            reading = bus.read_states([servo_id], check=False)[servo_id]
            still = _shutdown(reading.errors)
            if still:
                self._judge(bus, reading, afresh=True)
                return f"servo {servo_id} still reports {', '.join(still)} after {how}; " + _advice(
                    still, reading
                )
        standing = [f for f in self._judge(bus, reading, afresh=True) if f.level == "fault"]
        if standing:
            return "; ".join(f.describe() for f in standing) + "; " + _advice((), reading, standing)
        self._enable(bus, servo_id, protocol)
        bus.clear_fault(servo_id)
        return None

    @staticmethod
    def _enable(bus: DynamixelBus, servo_id: int, protocol: int) -> None:
        """Torque on again where the servo stands (1.0 also needs its Torque Limit back above 0)."""
        limit_reg = "torque_limit" if protocol == 1 else None
        torque = bus.read_register(servo_id, "torque_enable")
        limp = limit_reg is not None and bus.read_register(servo_id, limit_reg) == 0
        if torque and not limp:
            return
        present = bus.read_register(servo_id, "present_position")
        bus.write_register(servo_id, "goal_position", present)
        if limit_reg is not None and limp:
            bus.write_register(servo_id, limit_reg, bus.read_register(servo_id, "max_torque"))
        bus.write_register(servo_id, "torque_enable", 1)
        log.info("servo_torque_restored", servo_id=servo_id)


def _shutdown(errors: Sequence[str]) -> tuple[str, ...]:
    return tuple(n for n in errors if n in faults.SHUTDOWN_FAULTS)


def _advice(names: Sequence[str], reading: ServoReading, findings: Sequence[Finding] = ()) -> str:
    reasons = {f.reason for f in findings}
    if "overheating" in names or "overheat" in reasons:
        return f"let it cool (now {reading.temperature_c} °C) and reset again"
    if "voltage" in reasons:
        return f"check the supply (now {reading.voltage_v:g} V) and reset again"
    return "check the servo for a jam or a short and power-cycle it"
