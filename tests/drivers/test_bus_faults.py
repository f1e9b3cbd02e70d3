"""One test per bus fault: the typed exception, the recovery, the counters and the events. The bus-level
faults are injected on both transports (a pty through the OS's serial layer, the in-process cable); the
gripper's recoveries run in-process on a simulated clock."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from daemon.clock import RealClock
from drivers.dynamixel import (
    BusConfig,
    BusTimeout,
    DeviceEvent,
    DynamixelBus,
    DynamixelGripper,
    GripperSpec,
    ServoChain,
)
from drivers.dynamixel.faults import error_names, hardware_error_names
from drivers.dynamixel.protocol import encode_status
from drivers.errors import BusLost, DriverError, ServoFault
from drivers.interfaces import Clock
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from tests.fakes.devices import (
    PATIENT_S,
    TRANSPORTS,
    MugBetweenPads,
    PlantForceSensor,
    opener,
    run_on,
    serving,
)


@pytest.fixture(params=TRANSPORTS)
def chain_1(
    request: pytest.FixtureRequest,
) -> Iterator[tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]]]:
    events: list[DeviceEvent] = []
    clock = RealClock()  # the bus alone: its waits are on the device, its event times on any clock
    with serving(ServoChainSimulator(default_chain()), request.param, clock) as sim:
        bus = DynamixelBus(
            BusConfig(sim.device_path),
            clock=clock,
            on_event=events.append,
            read_timeout_s=PATIENT_S if request.param == "pty" else 0.01,
            open_serial=sim.open_serial,
        )
        with bus:
            bus.verify(default_chain())
            yield sim, bus, events


IDS = [1, 2, 3, 4, 5, 6]


def test_protocol_1_error_bits_decode_to_names() -> None:
    assert error_names(1, 0b0111_1111) == (
        "input_voltage",
        "angle_limit",
        "overheating",
        "range",
        "checksum",
        "overload",
        "instruction",
    )
    assert error_names(1, 0x20) == ("overload",)


def test_protocol_2_error_byte_and_hardware_status_decode_to_names() -> None:
    assert error_names(2, 0x80 | 3) == ("crc", "alert")
    assert hardware_error_names(0b0011_1101) == (
        "input_voltage",
        "overheating",
        "motor_encoder",
        "electrical_shock",
        "overload",
    )


def test_overload_in_a_bulk_read_raises_servo_fault_and_is_logged_once(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    sim.overload(4)
    for _ in range(2):
        with pytest.raises(ServoFault) as raised:
            bus.read_states(IDS)
        assert raised.value.servo_id == 4
        assert raised.value.bits == ("overload",)
    assert (
        str(raised.value)
        == f"servo 4 on {sim.device_path} reports overload; its torque is off until the fault is cleared"
    )
    assert [e.kind for e in events] == ["servo_fault"]


def test_sync_read_on_protocol_2_never_loses_the_error_byte() -> None:
    chain = ((1, "XL430-W250"), (2, "XM430-W350"), (3, "XL330-M288"))
    with (
        ServoChainSimulator(chain, protocol=2) as sim,
        DynamixelBus(
            BusConfig(sim.device_path, protocol=2), clock=RealClock(), read_timeout_s=PATIENT_S
        ) as bus,
    ):
        bus.verify(chain)
        assert set(bus.read_states([1, 2, 3])) == {1, 2, 3}
        sim.overload(2)
        with pytest.raises(ServoFault) as raised:
            bus.read_states([1, 2, 3])
        assert (raised.value.servo_id, raised.value.bits) == (2, ("overload",))


def test_a_transient_missing_status_is_retried_and_counted(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    sim.drop(2)
    readings = bus.read_states(IDS)
    assert set(readings) == set(IDS)
    assert bus.counters[2].retries == 1
    assert bus.counters[2].timeouts == 1
    assert events == []


def test_a_corrupt_status_is_retried_never_accepted(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, _ = chain_1
    sim.corrupt(5)
    readings = bus.read_states(IDS)
    assert readings[5].position_rad == pytest.approx(0.0, abs=0.01)
    assert bus.counters[5].corrupt == 1
    assert bus.counters[5].retries == 1


def test_a_silent_servo_faults_after_the_bounded_retries_and_only_it_is_blamed(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    sim.silence(3)
    with pytest.raises(BusTimeout) as raised:
        bus.read_states(IDS)
    assert str(raised.value) == (
        f"servo(s) 3 did not answer on {sim.device_path} after 3 tries; "
        "check the cable and power of the chain"
    )
    assert bus.counters[3].retries == 3
    assert [(e.kind, e.detail["servo_id"]) for e in events] == [("servo_fault", 3)]
    sim.silence(3, on=False)
    bus.read_states(IDS)
    assert [e.kind for e in events] == ["servo_fault", "servo_recovered"]


def test_usb_unplug_reports_bus_lost_and_replug_reconnects(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    sim.unplug()
    with pytest.raises(BusLost) as raised:
        bus.read_states(IDS)
    assert isinstance(raised.value, ConnectionError)
    assert raised.value.port == sim.device_path
    assert str(raised.value).startswith(f"servo bus {sim.device_path} is gone (")
    assert str(raised.value).endswith("plug the USB adapter back in to reconnect")
    sim.replug()
    assert set(bus.read_states(IDS)) == set(IDS)
    assert [e.kind for e in events] == ["bus_lost", "bus_restored"]


def test_a_usb_glitch_is_absorbed_by_closing_and_reopening_the_port(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    sim.unplug()
    sim.replug()
    assert set(bus.read_states(IDS)) == set(IDS)
    bus.write_register(1, "led", 1)
    assert [e.kind for e in events] == ["bus_lost", "bus_restored"]


def gripper_world(clock: Clock, contact_aperture_m: float) -> tuple[GripperSpec, MugBetweenPads]:
    spec = GripperSpec(overload_retries=2)
    plant = MugBetweenPads(
        spec.servo_id, spec.angle_for(contact_aperture_m), clock=clock.monotonic, stiffness_n_per_rad=200.0
    )
    return spec, plant


def gripper_chain(sim: ServoChainSimulator, clock: Clock, model: str, **kw: object) -> ServoChain:
    config = BusConfig(sim.device_path, protocol=sim.protocol)
    return ServoChain(config, [(6, model)], clock=clock, open_serial=opener(sim), read_timeout_s=0.01, **kw)  # type: ignore[arg-type]


@pytest.mark.parametrize(("protocol", "model"), [(1, "AX-12A"), (2, "XL330-M288")])
def test_gripper_overload_is_recovered_and_the_grasp_retried_at_a_lower_limit(
    protocol: int, model: str
) -> None:
    events: list[DeviceEvent] = []

    async def body(clock: Clock) -> None:
        spec, plant = gripper_world(clock, 0.074)
        spec = GripperSpec(model=model, overload_retries=2, aperture_map=spec.aperture_map)
        sim = ServoChainSimulator([(6, model)], protocol=protocol, plant=plant)  # type: ignore[arg-type]
        with serving(sim, "inprocess", clock):
            async with (
                gripper_chain(sim, clock, model, on_event=events.append) as chain,
                DynamixelGripper(chain, spec, PlantForceSensor(plant, clock)) as gripper,
            ):
                await gripper.open()
                sim.overload(6, now=False, repeats=2)  # trips on the next two goals, as a jammed gripper
                result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
                assert result.held
                assert gripper.overload_recoveries == 2
                limit_register = "torque_limit" if protocol == 1 else "goal_pwm"
                full = spec.spec.default_torque_limit
                assert sim.servo(6).get(limit_register) == round(full * 0.6 * 0.75 * 0.75)

    run_on("inprocess", body)
    kinds = [e.kind for e in events]
    assert kinds.count("gripper_overload_recovered") == 2
    assert kinds[0] == "servo_fault"


def test_gripper_faults_after_the_allowed_overload_recoveries() -> None:
    async def body(clock: Clock) -> None:
        spec, plant = gripper_world(clock, 0.074)
        with serving(ServoChainSimulator([(6, "AX-12A")], plant=plant), "inprocess", clock) as sim:
            async with (
                gripper_chain(sim, clock, "AX-12A") as chain,
                DynamixelGripper(chain, spec, PlantForceSensor(plant, clock)) as gripper,
            ):
                await gripper.open()
                sim.overload(6, now=False, repeats=10)
                with pytest.raises(ServoFault) as raised:
                    await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
                assert isinstance(raised.value, DriverError)
                assert str(raised.value) == (
                    "gripper servo 6 overloaded 3 times while closing, the last time at 34% of full torque; "
                    "check the gripper for a jam and power-cycle the servo"
                )
                assert gripper.overload_recoveries == 2

    run_on("inprocess", body)


def test_an_overload_in_an_answer_without_data_still_raises(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, _ = chain_1
    sim.silence(4)
    sim.inject_garbage(encode_status(1, 4, 0x20))  # servo 4 answers "overload" and nothing else
    with pytest.raises(ServoFault) as raised:
        bus.read_states([4])
    assert (raised.value.servo_id, raised.value.bits) == (4, ("overload",))


def test_an_unplug_inside_an_sdk_sync_write_does_not_leave_the_port_busy(
    chain_1: tuple[ServoChainSimulator, DynamixelBus, list[DeviceEvent]],
) -> None:
    sim, bus, events = chain_1
    goals = dict.fromkeys(IDS, (0.1, 1.0))
    sim.unplug()
    with pytest.raises(BusLost):
        bus.write_goals(goals)  # pyserial raises inside dynamixel-sdk's txPacket, which set is_using first
    sim.replug()
    bus.write_goals(goals)
    assert set(bus.read_states(IDS)) == set(IDS)
    assert [e.kind for e in events] == ["bus_lost", "bus_restored"]
