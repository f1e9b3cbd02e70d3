"""The systemd notification protocol (sd_notify), in pure Python over a unix datagram socket.

Under a ``Type=notify`` unit systemd passes ``NOTIFY_SOCKET`` (a path, or ``@name`` for an abstract socket)
and, with ``WatchdogSec=``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``. The daemon says ``READY=1`` once it
serves, pings ``WATCHDOG=1`` from its event loop at half the watchdog interval (so a stuck loop gets the
service restarted), and says ``STOPPING=1`` when shutting down. Outside systemd every call is a no-op.

Sending never blocks and never raises: a notification that cannot be delivered is logged once (and once
more when delivery works again), because losing a status line must not take the robot down.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from types import TracebackType

import structlog

log = structlog.get_logger(__name__)


class SdNotifier:
    """Sends sd_notify messages to one socket; a context manager that closes it."""

    def __init__(self, address: str | None, *, watchdog_usec: int | None = None) -> None:
        """``address`` is ``NOTIFY_SOCKET`` as systemd sets it (``@`` = abstract namespace); None disables."""
        self.address = address
        self._watchdog_usec = watchdog_usec
        self._sock: socket.socket | None = None
        self._failing = False
        if address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.setblocking(False)

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, *, pid: int | None = None) -> SdNotifier:
        """The notifier systemd set up for this process, or a disabled one outside systemd.

        The watchdog applies only when ``WATCHDOG_PID`` is unset or names this process (``pid``, default
        ``os.getpid()``), as sd_watchdog_enabled(3) specifies; malformed values disable it.
        """
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET") or None
        usec: int | None = None
        raw_usec = env.get("WATCHDOG_USEC", "")
        raw_pid = env.get("WATCHDOG_PID", "")
        own_pid = os.getpid() if pid is None else pid
        if raw_usec.isdigit() and int(raw_usec) > 0 and (not raw_pid or raw_pid == str(own_pid)):
            usec = int(raw_usec)
        elif raw_usec:
            log.warning("sd_watchdog_ignored", watchdog_usec=raw_usec, watchdog_pid=raw_pid, pid=own_pid)
        return cls(address, watchdog_usec=usec)

    @property
    def enabled(self) -> bool:
        """True when there is a socket to notify (the process runs under a Type=notify unit)."""
        return self._sock is not None

    @property
    def watchdog_interval_s(self) -> float | None:
        """systemd's watchdog timeout in seconds (ping at half of it), or None when there is no watchdog."""
        return None if self._watchdog_usec is None else self._watchdog_usec / 1e6

    def ready(self, status: str | None = None) -> bool:
        """Startup is complete: systemd marks the unit active and starts the watchdog."""
        return self.notify("READY=1", *self._status_field(status))

    def watchdog(self) -> bool:
        """The event loop is alive; call at half of ``watchdog_interval_s``."""
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        """Shutdown has begun (motion stopping, recording closing)."""
        return self.notify("STOPPING=1", *self._status_field(status))

    def status(self, text: str) -> bool:
        """A one-line status shown by ``systemctl status``."""
        return self.notify(*self._status_field(text))

    def extend_timeout(self, seconds: float) -> bool:
        """Ask for more time in the current start or stop phase (e.g. finishing a large recording)."""
        return self.notify(f"EXTEND_TIMEOUT_USEC={max(1, round(seconds * 1e6))}")

    def notify(self, *fields: str) -> bool:
        """Send ``KEY=VALUE`` fields as one datagram; True when systemd's socket accepted it."""
        if self._sock is None or self.address is None or not fields:
            return False
        target = "\0" + self.address[1:] if self.address.startswith("@") else self.address
        try:
            self._sock.sendto("\n".join(fields).encode(), target)
        except OSError as e:
            if not self._failing:
                log.warning("sd_notify_failed", socket=self.address, error=str(e), message=fields[0])
                self._failing = True
            return False
        if self._failing:
            log.info("sd_notify_recovered", socket=self.address)
            self._failing = False
        return True

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> SdNotifier:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    @staticmethod
    def _status_field(text: str | None) -> tuple[str, ...]:
        if text is None:
            return ()
        return ("STATUS=" + " ".join(text.split()),)  # one line: systemd splits fields on newlines
