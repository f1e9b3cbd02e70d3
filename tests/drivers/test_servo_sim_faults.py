"""The servo simulator's fault hooks for fault files, seen through the real bus driver: overheating and a
low supply set the registers and error bits as the firmware does (Protocol 1.0 and 2.0), a lasting overload
trips whenever the servo is driven, and corrupt packets come at a seeded rate."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from daemon.clock import RealClock
from drivers.dynamixel import BusConfig, BusTimeout, DeviceEvent, DynamixelBus
from drivers.errors import ServoFault
from drivers.sim.servo_chain import ServoChainSimulator
from tests.fakes.devices import inprocess_chain, serving

IDS = [1, 2, 3, 4, 5, 6]
CHAIN_2 = ((1, "XL430-W250"), (2, "XM430-W350"))


@pytest.fixture
def chain_1() -> Iterator[tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]]]:
    events: list[DeviceEvent] = []
    with inprocess_chain(read_timeout_s=0.01, on_event=events.append) as (sim, bus):
        yield sim, bus, events


@pytest.fixture
def chain_2() -> Iterator[tuple[ServoChainSimulator, DynamixelBus]]:
    clock = RealClock()
    with serving(ServoChainSimulator(CHAIN_2, protocol=2), "inprocess", clock) as sim:
        bus = DynamixelBus(
            BusConfig(sim.device_path, protocol=2),
            clock=clock,
            read_timeout_s=0.01,
            open_serial=sim.open_serial,
        )
        with bus:
            bus.verify(CHAIN_2)
            yield sim, bus


def test_protocol_1_overheating_reports_the_temperature_and_cuts_the_torque_until_cooled_and_cleared(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    bus.write_register(3, "torque_enable", 1)
    sim.overheat(3)
    with pytest.raises(ServoFault) as raised:
        bus.read_states(IDS)
    assert (raised.value.servo_id, raised.value.bits) == (3, ("overheating",))
    assert str(raised.value).endswith("reports overheating; its torque is off until the fault is cleared")
    limit = bus.read_register(3, "temperature_limit", check=False)
    assert bus.read_register(3, "present_temperature", check=False) == limit + 5 == 75
    assert bus.read_register(3, "torque_limit", check=False) == 0
    # Still hot: restoring the torque limit trips again at once.
    with pytest.raises(ServoFault):
        bus.write_register(3, "torque_limit", 1023)
    sim.overheat(3, on=False)
    assert bus.read_register(3, "present_temperature", check=False) == 32
    # Cooled: a 1.0 status reports the condition as it is now, but the shutdown holds until the torque
    # limit is written again.
    assert bus.read_states([3])[3].errors == ()
    assert bus.read_register(3, "torque_limit", check=False) == 0
    bus.write_register(3, "torque_limit", 1023)
    assert bus.read_states(IDS)[3].errors == ()
    assert [e.kind for e in events] == ["servo_fault", "servo_recovered"]


def test_protocol_1_low_voltage_sets_the_bit_while_it_lasts_and_keeps_the_torque(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    sim.brown_out(4)
    reading = bus.read_states(IDS)[4]
    assert reading.errors == ("input_voltage",)
    assert reading.voltage_v == pytest.approx(5.0)  # 1 V under the 6 V Min Voltage Limit
    assert bus.read_register(4, "min_voltage") == 60
    assert bus.read_register(4, "torque_limit") > 0
    sim.brown_out(4, on=False)
    reading = bus.read_states(IDS)[4]
    assert reading.errors == ()
    assert reading.voltage_v == pytest.approx(12.0)
    assert events == []  # a warning bit, not a shutdown: the driver reports it in the reading only


def test_protocol_2_low_voltage_raises_the_alert_until_a_reboot(
    chain_2: tuple[ServoChainSimulator, DynamixelBus],
) -> None:
    sim, bus = chain_2
    sim.brown_out(2)
    reading = bus.read_states([1, 2])[2]
    assert reading.errors == ("input_voltage",)
    assert reading.voltage_v == pytest.approx(8.5)  # 1 V under the X series' 9.5 V
    assert bus.read_register(2, "hardware_error_status") == 1
    sim.brown_out(2, on=False)
    assert bus.read_states([2])[2].errors == ("input_voltage",)  # latched
    bus.reboot(2, settle_s=0.0)
    assert bus.read_states([2])[2].errors == ()


def test_protocol_2_overheating_survives_a_reboot_while_hot(
    chain_2: tuple[ServoChainSimulator, DynamixelBus],
) -> None:
    sim, bus = chain_2
    sim.overheat(1)
    with pytest.raises(ServoFault) as raised:
        bus.read_states([1, 2])
    assert raised.value.bits == ("overheating",)
    assert bus.read_register(1, "present_temperature", check=False) == 85
    bus.reboot(1, settle_s=0.0)
    with pytest.raises(ServoFault):
        bus.read_states([1])
    sim.overheat(1, on=False)
    bus.reboot(1, settle_s=0.0)
    assert bus.read_states([1])[1].errors == ()


def test_a_lasting_overload_trips_whenever_the_servo_is_driven_until_it_ends(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, _ = chain_1
    bus.write_register(6, "torque_enable", 1)
    sim.keep_overloaded(6)
    for _ in range(3):
        bus.write_register(6, "torque_limit", 600)  # the gripper's recovery clears it...
        assert bus.read_states([6])[6].errors == ()
        bus.write_goals({6: (0.1, 1.0)})  # ...and the next goal trips it again
        with pytest.raises(ServoFault):
            bus.read_states([6])
    sim.keep_overloaded(6, on=False)
    bus.write_register(6, "torque_limit", 600)
    bus.write_goals({6: (0.1, 1.0)})
    assert bus.read_states([6])[6].errors == ()


def corrupt_counts(rate: float, seed: int) -> tuple[int, int]:
    with inprocess_chain(read_timeout_s=0.005) as (sim, bus):
        sim.corrupt_fraction(rate, seed=seed)
        for _ in range(10):
            assert set(bus.read_states(IDS)) == set(IDS)
        return sim.packets_corrupted, sum(c.corrupt for c in bus.counters.values())


def test_a_corrupt_fraction_is_retried_and_counted_the_same_way_every_run() -> None:
    first = corrupt_counts(0.05, seed=7)
    assert first == corrupt_counts(0.05, seed=7)
    corrupted, counted = first
    assert corrupted > 0
    assert counted >= corrupted


def test_every_packet_corrupt_is_a_servo_that_does_not_answer(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, _ = chain_1
    sim.corrupt_fraction(1.0, servo_id=5)
    with pytest.raises(BusTimeout) as raised:
        bus.read_states(IDS)
    assert raised.value.servo_id == 5
    sim.corrupt_fraction(0.0)
    assert set(bus.read_states(IDS)) == set(IDS)
