"""The pty servo chain answers the real dynamixel-sdk exactly like servos on a cable."""

from __future__ import annotations

import os
import time

import pytest
from dynamixel_sdk import PacketHandler, PortHandler, port_handler
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.dynamixel.protocol import Frame, Framer
from drivers.sim.servo_chain import ServoChainSimulator, default_chain

COMM_SUCCESS = 0
COMM_RX_TIMEOUT = -3001


@pytest.fixture(autouse=True)
def _patient_sdk(monkeypatch: pytest.MonkeyPatch) -> None:
    """The SDK waits 2 x its 16 ms latency timer for an answer; a loaded CI machine needs longer."""
    monkeypatch.setattr(port_handler, "LATENCY_TIMER", 100)


def open_port(path: str) -> PortHandler:
    port = PortHandler(path)
    assert port.openPort()
    assert port.setBaudRate(1_000_000)
    return port


def test_protocol_1_chain_answers_pings_with_each_model_number() -> None:
    with ServoChainSimulator(default_chain()) as sim:
        port = open_port(sim.device_path)
        packets = PacketHandler(1.0)
        models = [packets.ping(port, i)[0] for i in range(1, 7)]
        assert models == [310, 320, 310, 29, 12, 12]
        assert packets.ping(port, 7)[1] == COMM_RX_TIMEOUT
        port.closePort()


def test_protocol_2_broadcast_ping_lists_every_servo() -> None:
    with ServoChainSimulator([(1, "XL430-W250"), (2, "XM430-W350"), (3, "XL330-M288")], protocol=2) as sim:
        port = open_port(sim.device_path)
        found, result = PacketHandler(2.0).broadcastPing(port)
        assert result == COMM_SUCCESS
        assert found == {1: [1060, 41], 2: [1020, 41], 3: [1200, 41]}
        port.closePort()


@pytest.mark.parametrize(
    ("protocol", "model", "goal_address", "present_address", "size"),
    [
        (1, "MX-64T", 30, 36, 2),
        (2, "XM430-W350", 116, 132, 4),
    ],
)
def test_a_goal_written_with_torque_on_moves_the_present_position(
    protocol: int, model: str, goal_address: int, present_address: int, size: int
) -> None:
    with ServoChainSimulator([(1, model)], protocol=protocol) as sim:  # type: ignore[arg-type]
        port = open_port(sim.device_path)
        packets = PacketHandler(float(protocol))
        torque = 24 if protocol == 1 else 64
        assert packets.write1ByteTxRx(port, 1, torque, 1) == (COMM_SUCCESS, 0)
        write = packets.write2ByteTxRx if size == 2 else packets.write4ByteTxRx
        assert write(port, 1, goal_address, 2548) == (COMM_SUCCESS, 0)
        read = packets.read2ByteTxRx if size == 2 else packets.read4ByteTxRx
        deadline = time.monotonic() + 30  # the simulated servo moves on the wall clock: late when loaded
        while read(port, 1, present_address)[0] != 2548 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert read(port, 1, present_address) == (2548, COMM_SUCCESS, 0)
        port.closePort()


def test_a_servo_set_to_another_baud_rate_stops_hearing_the_host() -> None:
    with ServoChainSimulator([(1, "AX-12A")]) as sim:
        port = open_port(sim.device_path)
        packets = PacketHandler(1.0)
        assert packets.write1ByteTxRx(port, 1, 4, 34)[0] in (COMM_SUCCESS, COMM_RX_TIMEOUT)  # 57600 bps
        assert packets.ping(port, 1)[1] == COMM_RX_TIMEOUT
        port.setBaudRate(57_600)
        assert packets.ping(port, 1)[:2] == (12, COMM_SUCCESS)
        port.closePort()


def test_protocol_1_overload_latches_the_error_bit_and_zeroes_the_torque_limit() -> None:
    with ServoChainSimulator([(6, "AX-12A")]) as sim:
        port = open_port(sim.device_path)
        packets = PacketHandler(1.0)
        sim.overload(6)
        assert packets.read2ByteTxRx(port, 6, 34) == (0, COMM_SUCCESS, 0x20)
        assert packets.read2ByteTxRx(port, 6, 34) == (0, COMM_SUCCESS, 0x20)
        assert packets.write2ByteTxRx(port, 6, 34, 1023) == (COMM_SUCCESS, 0)
        assert packets.read2ByteTxRx(port, 6, 34) == (1023, COMM_SUCCESS, 0)
        port.closePort()


def test_protocol_2_overload_raises_the_alert_until_reboot() -> None:
    with ServoChainSimulator([(1, "XL430-W250")], protocol=2) as sim:
        port = open_port(sim.device_path)
        packets = PacketHandler(2.0)
        sim.overload(1)
        assert packets.read1ByteTxRx(port, 1, 70) == (0x20, COMM_SUCCESS, 0x80)
        assert packets.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0x80)
        assert packets.read1ByteTxRx(port, 1, 64)[0] == 0
        assert packets.reboot(port, 1) == (COMM_SUCCESS, 0)
        assert packets.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)
        port.closePort()


def test_a_silenced_servo_times_out_and_answers_again_when_released() -> None:
    with ServoChainSimulator([(1, "MX-28T")]) as sim:
        port = open_port(sim.device_path)
        packets = PacketHandler(1.0)
        sim.silence(1)
        assert packets.ping(port, 1)[1] == COMM_RX_TIMEOUT
        sim.silence(1, on=False)
        assert packets.ping(port, 1)[1] == COMM_SUCCESS
        port.closePort()


def test_unplugging_makes_the_device_path_vanish_and_replugging_restores_it() -> None:
    with ServoChainSimulator([(1, "MX-28T")]) as sim:
        path = sim.device_path
        sim.unplug()
        assert not os.path.exists(path)
        sim.replug()
        port = open_port(path)
        assert PacketHandler(1.0).ping(port, 1)[1] == COMM_SUCCESS
        port.closePort()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from([1, 2]),
    st.sampled_from([1, 2, 3, 0xFE]),
    st.sampled_from([0x01, 0x02, 0x03, 0x04, 0x05, 0x08, 0x82, 0x83, 0x92, 0x55, 0x7F]),
    st.binary(max_size=24),
)
def test_the_simulated_servos_survive_any_instruction(
    protocol: int, sid: int, code: int, params: bytes
) -> None:
    chain = [(1, "MX-64T"), (2, "AX-12A")] if protocol == 1 else [(1, "XL430-W250"), (2, "XM430-W350")]
    sim = ServoChainSimulator(chain, protocol=protocol, wire_timing=False)  # type: ignore[arg-type]
    servos = [sim.servo(1), sim.servo(2)]
    replies = sim._dispatch(Frame(sid, code, params), servos)
    for _, packet in replies:
        assert len(Framer(protocol).feed(packet)) == 1  # type: ignore[arg-type]
    assert {s.servo_id for s in servos} <= set(range(253))
