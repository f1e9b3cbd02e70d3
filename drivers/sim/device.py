"""A simulated serial device on either transport: a pseudo-terminal served by its own thread, or in-process.

``start()`` puts the device on a pseudo-terminal (``drivers.sim.pty_link``) and serves it from a thread in
wall-clock time: the host opens ``device_path`` with pyserial as it would a USB adapter, through the
kernel's tty layer. ``start_in_process(clock)`` puts it on an ``InProcessCable`` instead: the host opens
``device_path`` with ``open_serial``, its writes reach the device at once and whatever the device does over
time runs on ``clock`` (a simulated clock makes it deterministic and as fast as the machine allows). The
device's behaviour, and the bytes, are the same on both.
"""

from __future__ import annotations

import asyncio
import threading
from types import TracebackType
from typing import Protocol, Self

from drivers.interfaces import Clock
from drivers.serial_port import OpenSerial
from drivers.sim.inprocess import InProcessCable
from drivers.sim.pty_link import PtyLink


class DeviceLink(Protocol):
    """The device's end of its cable, whichever the transport."""

    device_path: str

    @property
    def plugged(self) -> bool: ...

    def write(self, data: bytes) -> None: ...

    def host_baudrate(self) -> int | None: ...

    def unplug(self) -> None: ...

    def plug(self) -> None: ...

    def close(self) -> None: ...


class SimulatedDevice:
    """Base of the device simulators: the transport and its life cycle, as a context manager (pty).

    Subclasses implement :meth:`_serve` (the pty thread's loop, until ``self._stop`` is set),
    :meth:`_received` (bytes from the host, in-process, on the host's thread) and may override
    :meth:`_prepare` (once the link exists, before serving) and, with ``streams = True``, :meth:`_run_on`
    (the device's own activity in time on an in-process clock, as an asyncio task)."""

    streams = False  # whether the device does something by itself over time (then _run_on is its task)

    def __init__(self, name: str, *, thread_name: str) -> None:
        self._name = name
        self._thread_name = thread_name
        self._link: DeviceLink | None = None
        self._thread: threading.Thread | None = None
        self._task: asyncio.Task[None] | None = None
        self._stop = threading.Event()
        self._open_serial: OpenSerial | None = None

    @property
    def device_path(self) -> str:
        if self._link is None:
            raise RuntimeError(f"the simulated {self._name} is not running; start() it or use it in a with")
        return self._link.device_path

    @property
    def open_serial(self) -> OpenSerial | None:
        """How a host opens ``device_path``: None on a pseudo-terminal (pyserial opens it like hardware),
        the cable's opener in-process."""
        return self._open_serial

    @property
    def in_process(self) -> bool:
        return self._open_serial is not None

    def start(self) -> Self:
        """On a fresh pseudo-terminal, served by a thread in wall-clock time."""
        self._link = PtyLink(self._name)
        self._prepare()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=self._thread_name, daemon=True)
        self._thread.start()
        return self

    def start_in_process(self, clock: Clock) -> Self:
        """On an in-process cable; a device that streams does so on ``clock``, as a task of the running
        event loop (the clock's)."""
        cable = InProcessCable(self._name, self._received, prompt=self._answers_at_once)
        self._link = cable
        self._open_serial = cable.open_serial
        self._prepare()
        if self.streams:
            self._task = asyncio.get_running_loop().create_task(self._run_on(clock), name=self._thread_name)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._task is not None:
            self._task.cancel()
            self._task = None
        if self._thread is not None:
            self._thread.join(timeout=2)
            self._thread = None
        if self._link is not None:
            self._link.close()
            self._link = None
        self._open_serial = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    def unplug(self) -> None:
        """Pull the USB adapter: the host's port fails and the device path disappears."""
        if self._link is not None:
            self._link.unplug()
            self._unplugged()

    def replug(self) -> None:
        """Plug the adapter back in: the device path reappears (on a fresh pty)."""
        if self._link is not None:
            self._link.plug()

    def _prepare(self) -> None:
        """Hook run after the link is opened and before the device starts serving."""

    def _unplugged(self) -> None:
        """Hook run when the adapter is pulled (forget half-received bytes)."""

    def _serve(self) -> None:
        raise NotImplementedError

    def _received(self, data: bytes) -> None:
        raise NotImplementedError

    def _answers_at_once(self) -> bool:
        """In-process: whether everything the host writes now is answered in full before its write returns
        (a device that answers requests, with nothing withheld); by default it is not."""
        return False

    async def _run_on(self, clock: Clock) -> None:
        """What the device does over time by itself (nothing, unless a subclass streams)."""
