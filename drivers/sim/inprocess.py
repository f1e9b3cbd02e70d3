"""An in-process serial cable: the same bytes between the real drivers and the device simulators, no tty.

``InProcessCable`` connects a host (dynamixel-sdk's port handler under ``DynamixelBus``, or ``FsrReader``)
to a simulator living in this process. What the host writes reaches the simulator at once, on the host's
thread (a bus transaction's answer is ready before the driver starts waiting for it); what the simulator
sends waits in the port's buffer in memory. The port's ``fileno`` is readable while bytes wait, so the host
waits for them with ``select`` or ``loop.add_reader`` exactly as it does on a serial adapter (or, knowing
the port is in-process, asks ``InProcessPort.pending``, with no system call). A pseudo-terminal carries the
same bytes with the kernel's latency on every hop, which caps how fast a simulated cell can run; this cable
has none, and on a simulated clock the answers take no simulated time.

Unplugging hangs the host's port up (it reads end-of-file, then every read and write fails, as with a
pulled USB adapter) and refuses to open it until it is plugged back in.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable

import serial

from drivers.serial_port import SerialPort

INPROCESS_PREFIX = "inprocess:"


class InProcessPort:
    """The host's end of the cable: a non-blocking pyserial-like port (``drivers.serial_port.SerialPort``).

    What the device sends waits in a buffer in memory: reading it, or asking how much there is, makes no
    system call. The port's ``fileno`` is a pipe that is readable while the buffer holds bytes (or the
    cable is pulled: then it reads end-of-file), for a host that waits with ``select`` or
    ``loop.add_reader``; it is kept up to date from the first time it is asked for, so a host that never
    waits on it (the bus on a simulated clock while every answer is there at once) costs no system call.
    """

    # Bytes the device may send ahead of the host's reads before further ones are lost, as with a pipe's
    # buffer (what the port kept its bytes in before).
    CAPACITY = 65536

    def __init__(self, cable: InProcessCable, baudrate: int) -> None:
        self._cable = cable
        self.baudrate = baudrate
        self._buf = bytearray()
        self._read_fd, self._write_fd = os.pipe()  # the readiness pipe: one byte while bytes wait
        os.set_blocking(self._read_fd, False)
        os.set_blocking(self._write_fd, False)
        self._watched = False  # fileno() was asked for: keep the pipe's readiness up to date
        self._rung = False  # the pipe holds its byte
        self._closed = False
        self._hung_up = False
        self._lock = threading.Lock()

    @property
    def in_waiting(self) -> int:
        self._check_open()
        return len(self._buf)

    def read(self, size: int = 1) -> bytes:
        self._check_open()
        with self._lock:
            buf = self._buf
            if not buf:
                return b""
            size = max(1, size)
            if size >= len(buf):
                data = bytes(buf)
                buf.clear()
            else:
                data = bytes(buf[:size])
                del buf[:size]
            if not buf and self._rung:
                self._quiet()
            return data

    def write(self, data: bytes) -> int:
        self._check_open()
        if self._hung_up:
            raise serial.SerialException(f"write failed on {self._cable.device_path}: the cable is unplugged")
        payload = bytes(data)
        self._cable.received(payload)
        return len(payload)

    def fileno(self) -> int:
        self._check_open()
        if not self._watched:
            with self._lock:
                self._watched = True
                if self._buf and not self._rung and not self._hung_up:
                    self._ring()
        return self._read_fd

    def pending(self) -> bool:
        """Whether a read would return at once (bytes wait, or end-of-file once the cable is pulled): what
        ``select`` on ``fileno`` says, without a system call."""
        return bool(self._buf) or self._hung_up

    def answers_at_once(self) -> bool:
        """Whether the device has answered whatever is written before the write returns, and withholds
        nothing now (``InProcessCable``'s ``prompt``): a host never needs to wait for it."""
        return not self._hung_up and self._cable.prompt()

    def reset_input_buffer(self) -> None:
        with self._lock:
            if self._buf:
                self._buf.clear()
            if self._rung:
                self._quiet()

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            os.close(self._read_fd)
            if not self._hung_up:
                os.close(self._write_fd)
        self._cable.host_closed(self)

    # --- the device's side ---------------------------------------------------------------------------------

    def deliver(self, data: bytes) -> None:
        """Bytes from the device to the host; lost when the host reads too slowly (a full buffer)."""
        with self._lock:
            if not data or self._closed or self._hung_up or len(self._buf) + len(data) > self.CAPACITY:
                return
            self._buf += data
            if self._watched and not self._rung:
                self._ring()

    def hang_up(self) -> None:
        """The cable was pulled: the host reads what was sent, then end-of-file, then fails."""
        with self._lock:
            if self._closed or self._hung_up:
                return
            self._hung_up = True
            os.close(self._write_fd)  # the pipe reads end-of-file once its byte is taken

    def _ring(self) -> None:
        os.write(self._write_fd, b"\x00")
        self._rung = True

    def _quiet(self) -> None:
        with contextlib.suppress(BlockingIOError):
            os.read(self._read_fd, 1)
        self._rung = False

    def _check_open(self) -> None:
        if self._closed:
            raise serial.SerialException("Attempting to use a port that is not open")


class InProcessCable:
    """A simulated serial cable named ``inprocess:<name>``; ``received`` is the simulator's input, called
    on the host's thread with every write; ``prompt`` says whether the device answers everything written
    to it now before the write returns (default: it says nothing, so a host waits as on a real port)."""

    def __init__(
        self, name: str, received: Callable[[bytes], None], *, prompt: Callable[[], bool] | None = None
    ) -> None:
        self.device_path = INPROCESS_PREFIX + name
        self._received = received
        self.prompt: Callable[[], bool] = prompt or _never
        self._lock = threading.Lock()
        self._port: InProcessPort | None = None
        self._plugged = True

    # --- the host's side ------------------------------------------------------------------------------

    def open_serial(self, port: str, baudrate: int) -> SerialPort:
        """Open the host's end (``drivers.serial_port.OpenSerial``); as pyserial, SerialException when the
        name is not this cable's or the cable is unplugged."""
        if port != self.device_path:
            raise serial.SerialException(f"could not open port {port}: no such in-process device")
        with self._lock:
            if not self._plugged:
                raise serial.SerialException(f"could not open port {port}: the cable is unplugged")
            previous, self._port = self._port, InProcessPort(self, baudrate)
            opened = self._port
        if previous is not None:
            previous.hang_up()
        return opened

    def received(self, data: bytes) -> None:
        self._received(data)

    def host_closed(self, port: InProcessPort) -> None:
        with self._lock:
            if self._port is port:
                self._port = None

    # --- the device's side ---------------------------------------------------------------------------

    @property
    def plugged(self) -> bool:
        return self._plugged

    def write(self, data: bytes) -> None:
        """Send to the host; lost when nothing is connected, as on a real cable."""
        port = self._port
        if port is not None and self._plugged:
            port.deliver(data)

    def host_baudrate(self) -> int | None:
        """The baud rate the host opened its end at, or None when it is not open."""
        port = self._port
        return port.baudrate if port is not None else None

    def unplug(self) -> None:
        with self._lock:
            self._plugged = False
            port, self._port = self._port, None
        if port is not None:
            port.hang_up()

    def plug(self) -> None:
        with self._lock:
            self._plugged = True

    def close(self) -> None:
        self.unplug()


def _never() -> bool:
    return False


__all__ = ["INPROCESS_PREFIX", "InProcessCable", "InProcessPort"]
