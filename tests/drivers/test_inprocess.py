"""The in-process serial cable: a pyserial-like port whose writes reach the simulator at once and whose
answers can be waited on with select, and that fails like a pulled USB adapter when unplugged."""

from __future__ import annotations

import select

import pytest
import serial

from drivers.sim.inprocess import InProcessCable


def echo_cable() -> tuple[InProcessCable, list[bytes]]:
    """A cable to a device that records what it receives and answers it reversed."""
    received: list[bytes] = []
    cable: InProcessCable

    def device(data: bytes) -> None:
        received.append(data)
        cable.write(data[::-1])

    cable = InProcessCable("ttyECHO", device)
    return cable, received


def test_a_write_is_answered_before_the_host_waits_and_select_sees_it() -> None:
    cable, received = echo_cable()
    port = cable.open_serial("inprocess:ttyECHO", 1_000_000)
    assert cable.host_baudrate() == 1_000_000
    assert port.read(10) == b""  # nothing yet, and no blocking
    assert port.write(b"\x01\x02\x03") == 3
    assert received == [b"\x01\x02\x03"]
    assert select.select([port.fileno()], [], [], 0)[0] == [port.fileno()]
    assert port.in_waiting == 3
    assert port.read(2) == b"\x03\x02"
    port.reset_input_buffer()
    assert port.in_waiting == 0
    port.close()
    port.close()
    assert cable.host_baudrate() is None
    with pytest.raises(serial.SerialException, match=r"^Attempting to use a port that is not open$"):
        port.read(1)


def test_only_the_cables_own_name_opens() -> None:
    cable, _ = echo_cable()
    with pytest.raises(
        serial.SerialException, match=r"^could not open port /dev/ttyUSB0: no such in-process device$"
    ):
        cable.open_serial("/dev/ttyUSB0", 115_200)


def test_unplugging_hangs_the_port_up_and_refuses_to_open_until_plugged_back() -> None:
    cable, _ = echo_cable()
    port = cable.open_serial(cable.device_path, 115_200)
    cable.unplug()
    assert select.select([port.fileno()], [], [], 0)[0]  # the host wakes up ...
    assert port.read(1) == b""  # ... to end-of-file, as on a pulled adapter
    with pytest.raises(serial.SerialException, match=r"^write failed on inprocess:ttyECHO: the cable is"):
        port.write(b"x")
    with pytest.raises(serial.SerialException, match=r"^could not open port inprocess:ttyECHO: the cable is"):
        cable.open_serial(cable.device_path, 115_200)
    port.close()
    cable.plug()
    again = cable.open_serial(cable.device_path, 115_200)
    again.write(b"ab")
    assert again.read(2) == b"ba"
    again.close()


def test_opening_again_hangs_up_the_previous_port() -> None:
    cable, _ = echo_cable()
    first = cable.open_serial(cable.device_path, 115_200)
    second = cable.open_serial(cable.device_path, 57_600)
    assert select.select([first.fileno()], [], [], 0)[0]  # hung up: end-of-file
    assert first.read(1) == b""
    with pytest.raises(serial.SerialException):
        first.write(b"x")
    second.write(b"xy")
    assert second.read(2) == b"yx"
    assert cable.host_baudrate() == 57_600
    first.close()
    second.close()
