"""The simulated serial cable on a pseudo-terminal (``drivers.sim.pty_link``)."""

from __future__ import annotations

import os
import threading

from drivers.sim.pty_link import PtyLink

# Only a hang can exceed this (a write that never returns); the work itself takes milliseconds.
_HANG_S = 60.0


def test_a_device_whose_host_stopped_reading_still_writes_and_closes() -> None:
    """With nobody reading, the pty's buffer fills; a write must neither block nor hold the link's lock, or
    a rig no daemon has connected to could never be stopped (its SIGTERM waited on ``unplug`` for ever)."""
    link = PtyLink("ttyTEST")
    host = os.open(link.device_path, os.O_RDWR | os.O_NOCTTY)  # opened, never read
    try:
        done = threading.Event()

        def flood() -> None:
            for _ in range(2_000):  # 2 MB: far more than a pty buffers
                link.write(b"x" * 1_000)
            done.set()

        writer = threading.Thread(target=flood, daemon=True)
        writer.start()
        writer.join(_HANG_S)
        assert done.is_set(), "a write blocked on a full buffer"
        link.close()  # takes the lock: returns only if no write holds it
        assert not link.plugged
        assert not os.path.exists(link.device_path)
    finally:
        os.close(host)


def test_what_the_host_reads_and_writes_still_arrives() -> None:
    link = PtyLink("ttyTEST")
    host = os.open(link.device_path, os.O_RDWR | os.O_NOCTTY)
    try:
        link.write(b"\xff\xff\x01\x02\x00\xfc")
        assert os.read(host, 64) == b"\xff\xff\x01\x02\x00\xfc"
        os.write(host, b"ping")
        assert link.read(timeout=_HANG_S) == b"ping"
        assert link.read(timeout=0.0) == b""  # nothing more sent
    finally:
        os.close(host)
        link.close()
