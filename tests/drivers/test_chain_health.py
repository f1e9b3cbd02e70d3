"""The servo chain's health (issue 13): voltage and temperature polled against the configured limits, the
reset check that clears a tripped servo as its protocol allows, the blame of a stalled chain, the
corruption-rate threshold and a lost bus failing fast. The real bus and chain on dynamixel-sdk talk to the
servo chain simulator over the in-process cable on a simulated clock."""

from __future__ import annotations

from collections.abc import Awaitable, Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.clock import SimulatedClock
from drivers.dynamixel import BusConfig, BusCorrupt, BusTimeout, DeviceEvent, ServoChain
from drivers.dynamixel.bus import DeviceWaits, DynamixelBus
from drivers.dynamixel.health import ChainHealth, HealthLimits, ServoHealthFault
from drivers.errors import BusLost
from drivers.serial_port import SerialPort
from drivers.sim.plant import FirstOrderPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain

IDS = [1, 2, 3, 4, 5, 6]
P2_CHAIN = tuple((i, "XL430-W250") for i in range(1, 4))
Body = Callable[[ServoChainSimulator, ServoChain, ChainHealth, list[DeviceEvent]], Awaitable[None]]


def run(body: Body, *, protocol: int = 1, limits: HealthLimits | None = None, **bus: object) -> None:
    """``body(sim, chain, health, events)`` on an in-process chain on a simulated clock."""
    clock = SimulatedClock()
    chain_spec = default_chain() if protocol == 1 else P2_CHAIN
    events: list[DeviceEvent] = []

    async def main() -> None:
        sim = ServoChainSimulator(chain_spec, protocol=protocol, plant=FirstOrderPlant(clock=clock.monotonic))  # type: ignore[arg-type]
        sim.start_in_process(clock)
        try:
            config = BusConfig(sim.device_path, protocol=protocol)  # type: ignore[arg-type]
            chain = ServoChain(
                config,
                chain_spec,
                clock=clock,
                read_timeout_s=0.005,
                on_event=events.append,
                open_serial=sim.open_serial,
                **bus,  # type: ignore[arg-type]
            )
            async with chain:
                await body(sim, chain, ChainHealth(chain, limits or HealthLimits()), events)
        finally:
            sim.stop()

    clock.run(main())


def detail(events: list[DeviceEvent], kind: str) -> list[tuple[object, ...]]:
    return [
        (e.detail["servo"], e.detail["reason"], e.detail.get("value"), e.detail.get("limit"))
        for e in events
        if e.kind == kind
    ]


# ---------------------------------------------------------------------------------------------- polling


def test_a_sagging_supply_warns_near_the_limit_faults_past_it_and_clears_when_back() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        await health.poll()
        assert ev == []
        sim.set_present_voltage(3, 10.3)
        await health.poll()
        await health.poll()  # once per level entered
        assert detail(ev, "servo_warning") == [(3, "voltage", 10.3, 10.5)]
        sim.set_present_voltage(3, 9.5)
        with pytest.raises(ServoHealthFault) as raised:
            await health.poll()
        assert str(raised.value) == "servo 3 supply voltage 9.5 V is past its limit 10 V"
        assert (raised.value.servo_id, raised.value.bits) == (3, ("voltage",))
        assert detail(ev, "servo_fault") == [(3, "voltage", 9.5, 10.0)]
        assert health.problems() == ("servo 3 is past its voltage limit; reset once it is back inside",)
        with pytest.raises(ServoHealthFault):
            await health.poll()  # it stands while the voltage does, and is reported once
        assert len(detail(ev, "servo_fault")) == 1
        sim.set_present_voltage(3, 12.0)
        await health.poll()
        assert [e.kind for e in ev][-1] == "servo_health_ok"
        assert health.problems() == ()

    run(body)


def test_a_6_v_reading_and_an_overvoltage_both_fault_naming_the_limit() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.set_present_voltage(2, 6.0)  # inside the servo's own 6-14 V window: no error bit
        sim.set_present_voltage(5, 13.7)
        with pytest.raises(ServoHealthFault) as raised:
            await health.poll()
        assert str(raised.value) == "servo 2 supply voltage 6 V is past its limit 10 V"
        assert detail(ev, "servo_fault") == [(2, "voltage", 6.0, 10.0)]
        assert detail(ev, "servo_warning") == [(5, "voltage", 13.7, 13.5)]
        sim.set_present_voltage(5, 14.5)  # past the config and the servo's own window: one event
        with pytest.raises(ServoHealthFault):
            await health.poll()
        assert detail(ev, "servo_fault") == [(2, "voltage", 6.0, 10.0), (5, "voltage", 14.5, 14.0)]

    run(body)


def test_the_input_voltage_error_bit_faults_even_inside_the_configured_window() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.servo(4).set("min_voltage", 115)  # this servo wants 11.5 V at least
        sim.set_present_voltage(4, 11.2)
        with pytest.raises(ServoHealthFault):
            await health.poll()
        fault = next(e for e in ev if e.kind == "servo_fault")
        assert (fault.detail["servo"], fault.detail["reason"], fault.detail["value"]) == (4, "voltage", 11.2)
        assert (fault.detail["limit"], fault.detail["error_bit"]) == (11.5, True)

    run(body)


def test_heat_warns_then_faults_past_the_configured_limit_even_without_the_error_bit() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.servo(3).set("temperature_limit", 99)  # the servo itself would not complain before 99 °C
        sim.set_present_temperature(3, 62)
        await health.poll()
        assert detail(ev, "servo_warning") == [(3, "overheat", 62.0, 60.0)]
        sim.set_present_temperature(3, 95)
        with pytest.raises(ServoHealthFault) as raised:
            await health.poll()
        assert str(raised.value) == "servo 3 temperature 95 °C is past its limit 70 °C"
        assert detail(ev, "servo_fault") == [(3, "overheat", 95.0, 70.0)]
        assert sim.servo(3).get("torque_limit") > 0  # no error bit, no shutdown: only the poll saw it
        sim.set_present_temperature(3, 69)  # inside again, but within the hysteresis: still a fault
        with pytest.raises(ServoHealthFault) as raised:
            await health.poll()
        assert str(raised.value) == "servo 3 temperature 69 °C is not yet back inside its limit 70 °C"
        sim.set_present_temperature(3, 50)
        await health.poll()
        assert [e.kind for e in ev][-1] == "servo_health_ok"

    run(body)


def test_an_overheating_shutdown_is_one_fault_event_with_its_temperature() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.set_present_temperature(2, 75)  # past the servo's own 70 °C: error bit and torque off
        assert sim.servo(2).get("torque_limit") == 0
        with pytest.raises(ServoHealthFault):
            await health.poll()
        with pytest.raises(ServoHealthFault):
            await health.poll()
        faults = [e for e in ev if e.kind == "servo_fault"]
        assert len(faults) == 1
        assert (faults[0].detail["servo"], faults[0].detail["reason"], faults[0].detail["value"]) == (
            2,
            "overheat",
            75.0,
        )

    run(body)


# ---------------------------------------------------------------------------------------------- reset


def test_reset_clears_a_protocol_1_overload_by_restoring_the_torque() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.overload(2)
        with pytest.raises(Exception, match="reports overload"):
            await chain.call(lambda bus: bus.read_states(IDS))
        assert health.problems() == ("servo 2 reports overload; reset to clear it",)
        assert await health.clear() == ()
        servo = sim.servo(2)
        assert (servo.get("torque_limit"), servo.get("torque_enable"), servo.hardware_error) == (1023, 1, 0)
        assert health.problems() == ()
        assert [e.kind for e in ev] == ["servo_fault", "servo_recovered"]
        await chain.call(lambda bus: bus.read_states(IDS))

    run(body)


def test_reset_clears_a_protocol_2_overload_by_reboot_and_enables_the_torque_again() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        await chain.call(lambda bus: bus.write_register(2, "torque_enable", 1))
        sim.overload(2)
        assert sim.servo(2).get("torque_enable") == 0
        seen = sim.packets_seen
        assert await health.clear() == ()
        servo = sim.servo(2)
        assert (servo.hardware_error, servo.get("torque_enable")) == (0, 1)
        assert sim.packets_seen > seen
        assert [e.kind for e in ev] == ["servo_fault", "servo_recovered"]

    run(body, protocol=2)


@pytest.mark.parametrize("protocol", [1, 2])
def test_reset_is_refused_while_the_cause_stays_and_clears_once_it_is_gone(protocol: int) -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        limit = sim.servo(3).get("temperature_limit")
        sim.set_present_temperature(3, limit + 5)
        how = "a reboot" if protocol == 2 else "restoring its torque limit"
        assert await health.clear() == (
            f"servo 3 still reports overheating after {how}; "
            f"let it cool (now {limit + 5} °C) and reset again",
        )
        sim.set_present_temperature(3, 40)
        assert await health.clear() == ()
        assert sim.servo(3).get("torque_enable") == 1
        assert health.problems() == ()

    run(body, protocol=protocol)


def test_reset_judges_afresh_a_servo_back_inside_its_limit() -> None:
    """The poll's hysteresis keeps a fault until the value is well inside; reset, asked for by a person,
    needs it only inside the limit."""

    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.servo(3).set("temperature_limit", 99)
        sim.set_present_temperature(3, 80)
        with pytest.raises(ServoHealthFault):
            await health.poll()
        sim.set_present_temperature(3, 69)
        with pytest.raises(ServoHealthFault):
            await health.poll()
        assert await health.clear() == ()
        assert health.problems() == ()
        assert [e.kind for e in ev] == ["servo_fault", "servo_warning"]  # 69 °C: past the warning level

    run(body)


def test_a_protocol_2_input_voltage_error_stays_latched_until_reset_reboots_the_servo() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.set_present_voltage(2, 5.5)  # below the servo's own 6 V
        with pytest.raises(ServoHealthFault) as raised:
            await health.poll()
        assert str(raised.value) == (
            "servo 2 supply voltage 5.5 V is past its limit 10 V (the servo reports the input voltage error)"
        )
        sim.set_present_voltage(2, 12.0)
        with pytest.raises(ServoHealthFault) as raised:  # Hardware Error Status holds it until a reboot
            await health.poll()
        assert str(raised.value) == (
            "servo 2 reports the input voltage error (supply voltage now 12 V, limit 16 V)"
        )
        assert await health.clear() == ()
        assert sim.servo(2).hardware_error == 0
        await health.poll()
        assert [e.kind for e in ev][-1] == "servo_health_ok"

    run(body, protocol=2)


def test_reset_names_a_silent_servo_and_a_lost_bus() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.silence(4)
        problems = await health.clear()
        assert problems == (
            f"MX-28T servo 4: servo(s) 4 did not answer on {sim.device_path} after 3 tries; check the cable "
            "and power of the chain",
        )
        sim.silence(4, on=False)
        sim.unplug()
        (lost,) = await health.clear()
        assert lost.startswith(f"servo bus {sim.device_path} is gone (")
        assert health.problems() == (
            f"servo bus {sim.device_path} is lost; plug the USB adapter back in and reset",
        )
        sim.replug()
        assert await health.clear() == ()
        assert [e.kind for e in ev] == ["servo_fault", "bus_lost", "bus_restored", "servo_recovered"]

    run(body)


# ---------------------------------------------------------------------------------------------- the bus


def test_a_short_glitch_on_one_servo_blames_only_that_servo() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.drop(3, packets=3)  # its next three answers are lost; servos 4-6 wait behind it each time
        with pytest.raises(BusTimeout) as raised:
            await chain.call(lambda bus: bus.read_states(IDS))
        assert str(raised.value).startswith(f"servo(s) 3 did not answer on {sim.device_path} after 3 tries")
        assert [(e.kind, e.detail["servo"], e.detail["reason"]) for e in ev] == [
            ("servo_fault", 3, "no_status")
        ]

    run(body)


def test_answers_that_stay_corrupt_fault_as_bus_corrupt_not_as_silence() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.corrupt(4, packets=10)
        with pytest.raises(BusCorrupt) as raised:
            await chain.call(lambda bus: bus.read_states(IDS))
        assert str(raised.value).startswith(
            f"servo(s) 4 answered only with corrupt packets on {sim.device_path} after 3 tries"
        )
        assert raised.value.bits == ("bus_corrupt",)
        assert [(e.kind, e.detail["servo"], e.detail["reason"]) for e in ev] == [
            ("servo_fault", 4, "bus_corrupt")
        ]

    run(body)


@pytest.mark.parametrize(("every", "faults"), [(3, True), (10, False)])
def test_a_corruption_rate_over_the_threshold_faults_with_bus_corrupt(every: int, faults: bool) -> None:
    """One answer in three corrupt (33 %) passes a 20 % threshold; one in ten never does."""

    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.corrupt_every(4, every)
        error: BusCorrupt | None = None
        reads = 0
        for reads in range(1, 201):  # noqa: B007 (how many it took is asserted)
            try:
                await chain.call(lambda bus: bus.read_states(IDS))
            except BusCorrupt as e:
                error = e
                break
        if faults:
            assert error is not None
            assert str(error).startswith(
                f"corrupt answers on {sim.device_path} passed 20% of the last 50 (servo 4: 11)"
            )
            assert 20 < reads < 50  # every read got its answer on a retry: none failed by itself
            assert [(e.kind, e.detail["reason"]) for e in ev] == [("servo_fault", "bus_corrupt")]
        else:
            assert (error, reads, ev) == (None, 200, [])
            assert chain.counters()[4].corrupt >= 19

    run(body, corrupt_rate_max=0.2, corrupt_window=50)


class _CountedWaits:
    """The bus's waits (``DeviceWaits``), each wait on the device noted in ``made``."""

    def __init__(self, inner: DeviceWaits) -> None:
        self.inner = inner
        self.made: list[tuple[str, float]] = []

    def now(self) -> float:
        return self.inner.now()

    def readable(self, port: SerialPort, timeout_s: float) -> bool:
        self.made.append(("readable", timeout_s))
        return self.inner.readable(port, timeout_s)

    def sleep(self, seconds: float) -> None:
        self.made.append(("sleep", seconds))
        self.inner.sleep(seconds)


def test_a_lost_bus_is_reported_once_and_every_access_fails_at_once_until_replugged() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, health: ChainHealth, ev: list[DeviceEvent]
    ) -> None:
        sim.unplug()
        waits = _CountedWaits(chain.bus.waits)
        chain.bus.waits = waits
        for _ in range(5):
            with pytest.raises(BusLost):
                await chain.call(lambda bus: bus.read_states(IDS))
        # No waits for a re-enumerating adapter (a 50 ms retry pause per access) nor for an answer: counted
        # on the bus's waits, not timed on the wall clock (a loaded machine stalls a thread for longer).
        assert waits.made == []
        chain.bus.waits = waits.inner
        assert chain.bus.lost
        assert [e.kind for e in ev] == ["bus_lost"]
        sim.replug()
        await chain.call(lambda bus: bus.read_states(IDS))
        assert [e.kind for e in ev] == ["bus_lost", "bus_restored"]

    run(body)


@settings(max_examples=60, deadline=None)
@given(
    window=st.integers(min_value=0, max_value=8),
    answers=st.lists(
        st.tuples(st.integers(min_value=1, max_value=3), st.booleans(), st.booleans()), max_size=80
    ),
)
def test_the_kept_count_of_corrupt_answers_is_the_windows_own(
    window: int, answers: list[tuple[int, bool, bool]]
) -> None:
    """The bus keeps each servo's count of corrupt answers in its window as answers come and go (judged on
    every read): it is always what counting the window would give, through resets too."""
    bus = DynamixelBus(BusConfig("inprocess:none"), clock=SimulatedClock(), corrupt_window=window)
    for servo_id, corrupt, reset in answers:
        bus._note_answer(servo_id, corrupt=corrupt)
        if reset:
            bus.reset_link_stats()
        for i in (1, 2, 3):
            assert bus._recent_corrupt.get(i, 0) == sum(bus._recent.get(i, ()))
