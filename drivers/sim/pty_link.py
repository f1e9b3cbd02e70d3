"""A serial device on a pseudo-terminal that can be unplugged and plugged back in.

The device is reached through a stable symlink (like ``/dev/serial/by-id/...``) that points at the current
pty slave. Unplugging closes both ends, so a host blocked in a read or write gets EIO as from a pulled USB
adapter, and removes the symlink; plugging back creates a fresh pty and points the symlink at it.
"""

from __future__ import annotations

import contextlib
import os
import select
import tempfile
import termios
import threading
import tty
from typing import Final

# termios speed constants -> baud, for reading the rate the host configured on its end.
_SPEEDS: Final[dict[int, int]] = {
    getattr(termios, f"B{rate}"): rate
    for rate in (
        9600,
        19200,
        38400,
        57600,
        115200,
        230400,
        460800,
        500000,
        576000,
        921600,
        1000000,
        1152000,
        2000000,
        2500000,
        3000000,
        3500000,
        4000000,
    )
    if hasattr(termios, f"B{rate}")
}


class PtyLink:
    """One end of a simulated serial cable; the other end is at :attr:`device_path`."""

    def __init__(self, name: str) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="dishbot-")
        self.device_path = os.path.join(self._dir.name, name)
        self._lock = threading.Lock()
        self._master = -1
        self._slave = -1
        self.plug()

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    def plug(self) -> None:
        """Create the pty (again) and point the device path at it."""
        with self._lock:
            if self._master >= 0:
                return
            master, slave = os.openpty()
            tty.setraw(master)
            tty.setraw(slave)
            # Writes never wait for the host: with nobody reading (a rig no daemon has connected to yet, a
            # host that died) the pty's buffer fills in seconds, and a blocking write would hold the lock
            # for ever, so that neither ``unplug`` nor ``close`` could return (the rig ignored SIGTERM).
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            tmp = self.device_path + ".new"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(os.ttyname(slave), tmp)
            os.replace(tmp, self.device_path)

    def unplug(self) -> None:
        """Close both ends (the host's next I/O fails with EIO) and make the device path disappear."""
        with self._lock:
            if self._master < 0:
                return
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.device_path)
            os.close(self._master)
            os.close(self._slave)
            self._master = self._slave = -1

    def read(self, timeout: float) -> bytes:
        """Whatever the host sent within ``timeout`` seconds; empty when nothing came or unplugged."""
        with self._lock:
            fd = self._master
            if fd < 0:
                ready = False
            else:
                try:
                    ready = bool(select.select([fd], [], [], timeout)[0])
                    return os.read(fd, 4096) if ready else b""
                except OSError:
                    return b""
        if not ready:
            threading.Event().wait(timeout)
        return b""

    def write(self, data: bytes) -> None:
        """Send to the host; silently lost when unplugged, as on a real cable, and what does not fit in a
        buffer the host has stopped reading is lost too, as from a serial adapter's full buffer."""
        with self._lock:
            if self._master < 0:
                return
            with contextlib.suppress(OSError):
                os.write(self._master, data)

    def host_baudrate(self) -> int | None:
        """The baud rate the host configured on its end, or None when unknown or unplugged."""
        with self._lock:
            if self._master < 0:
                return None
            try:
                attrs = termios.tcgetattr(self._master)
            except termios.error:
                return None
        return _SPEEDS.get(attrs[5])

    def close(self) -> None:
        self.unplug()
        self._dir.cleanup()
