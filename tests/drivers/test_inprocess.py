"""The in-process serial cable: a pyserial-like port whose writes reach the simulator at once and whose
answers can be waited on with select, and that fails like a pulled USB adapter when unplugged."""

from __future__ import annotations

import select

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.serial_port import SerialPort
from drivers.sim.inprocess import InProcessCable, InProcessPort


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


def readable(port: SerialPort) -> bool:
    return bool(select.select([port.fileno()], [], [], 0)[0])


def test_the_port_says_what_waits_without_a_system_call_and_select_agrees_once_asked() -> None:
    cable, _ = echo_cable()
    port = cable.open_serial(cable.device_path, 1_000_000)
    assert isinstance(port, InProcessPort)
    port.write(b"abc")
    assert port.pending()
    assert port.in_waiting == 3
    # Nobody waited on the descriptor so far; asked for it now, it is readable because bytes wait.
    assert readable(port)
    assert port.read(1) == b"c"
    assert readable(port)
    assert port.pending()
    assert port.read(10) == b"ba"
    assert not readable(port)
    assert not port.pending()
    port.write(b"xy")
    assert readable(port)
    assert port.pending()
    port.reset_input_buffer()
    assert not readable(port)
    assert not port.pending()
    assert port.in_waiting == 0
    cable.write(b"")  # nothing sent: nothing to wake for
    assert not readable(port)
    assert port.read(5) == b""
    cable.unplug()
    assert readable(port)
    assert port.pending()
    assert port.read(1) == b""
    port.close()


def test_what_was_sent_before_the_cable_is_pulled_is_read_then_end_of_file() -> None:
    cable, _ = echo_cable()
    port = cable.open_serial(cable.device_path, 115_200)
    assert not readable(port)
    port.write(b"12")
    cable.unplug()
    assert readable(port)
    assert port.read(10) == b"21"
    assert readable(port)  # end-of-file now
    assert port.read(10) == b""
    port.close()


@settings(max_examples=50, deadline=None)
@given(st.lists(st.binary(min_size=1, max_size=3000), max_size=60))
def test_bytes_past_a_full_buffer_are_lost_whole_as_with_a_slow_reader(chunks: list[bytes]) -> None:
    cable, _ = echo_cable()
    port = cable.open_serial(cable.device_path, 115_200)
    kept = b""
    for chunk in chunks:
        cable.write(chunk)
        if len(kept) + len(chunk) <= InProcessPort.CAPACITY:
            kept += chunk
    assert port.in_waiting == len(kept)
    assert port.read(len(kept) + 1) == kept
    assert not readable(port)
    port.close()
