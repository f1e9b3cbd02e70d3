"""The real daemon under a stand-in for systemd: notify lifecycle, watchdog pings, recording after a kill."""

from __future__ import annotations

import itertools
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from recorder import HEADER_TOPIC, read_messages
from tests.fakes.ports import free_port

ROBOT = "svc"
CHUNK_SIZE_BYTES = 4096  # small chunks: a kill can lose at most the one being written
WATCHDOG_S = 1.0  # the watchdog test's WATCHDOG_USEC: a ping every 0.5 s
PINGS = 9


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[socket.socket]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify.sock"))
    sock.settimeout(0.2)
    yield sock
    sock.close()


def start_daemon(
    tmp_path: Path, notify: socket.socket, *, watchdog_usec: int = 2_000_000
) -> subprocess.Popen[bytes]:
    config = tmp_path / "dishbot.toml"
    # Idle files keep telemetry at the full rate here, so the cut can be seen to within a joint sample.
    recording = f"idle_telemetry_hz = 100.0\nchunk_size_bytes = {CHUNK_SIZE_BYTES}\n"
    config.write_text(f'robot_id = "{ROBOT}"\n[recording]\n{recording}')
    env = {
        **os.environ,
        "NOTIFY_SOCKET": notify.getsockname(),
        "WATCHDOG_USEC": str(watchdog_usec),  # the daemon pings at half of it
    }
    env.pop("WATCHDOG_PID", None)
    listen = f"tcp/127.0.0.1:{free_port()}"
    command = [
        sys.executable,
        "-m",
        "cli.main",
        "run",
        "--sim",
        "--world",
        "kinematic",
        "--config",
        str(config),
    ]
    command += ["--record-dir", str(tmp_path / "rec"), "--listen", listen]
    with (tmp_path / "stderr.log").open("wb") as stderr:
        return subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=stderr)


def wait_for(sock: socket.socket, prefix: str, proc: subprocess.Popen[bytes]) -> tuple[float, str]:
    """The arrival time and text of the next notification starting with ``prefix``."""
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        try:
            message = sock.recv(4096).decode()
        except TimeoutError:
            if proc.poll() is not None:
                stderr = Path(notify_dir(sock), "stderr.log").read_text(errors="replace")
                pytest.fail(f"the daemon exited with {proc.returncode} before {prefix}:\n{stderr[-2000:]}")
            continue
        if message.startswith(prefix):
            return time.monotonic(), message
    pytest.fail(f"no {prefix} from the daemon within 30 s")


def grown(path: Path, size: int) -> int:
    """The file's size once it is larger than ``size`` (the writer flushed), within a generous 30 s."""
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        now = path.stat().st_size
        if now > size:
            return now
        time.sleep(0.02)
    pytest.fail(f"{path} did not grow past {size} bytes within 30 s: the writer does not flush")


def notify_dir(sock: socket.socket) -> str:
    return os.path.dirname(str(sock.getsockname()))


def the_recording(tmp_path: Path) -> Path:
    files = list((tmp_path / "rec").glob("*.mcap"))
    assert len(files) == 1, files
    return files[0]


@pytest.mark.slow
def test_daemon_notifies_ready_pings_the_watchdog_and_stops_cleanly_on_sigterm(
    tmp_path: Path, notify_socket: socket.socket
) -> None:
    proc = start_daemon(tmp_path, notify_socket, watchdog_usec=int(WATCHDOG_S * 1e6))
    try:
        _, ready = wait_for(notify_socket, "READY=1", proc)
        assert ready.splitlines()[1].startswith("STATUS=")
        pings = [wait_for(notify_socket, "WATCHDOG=1", proc)[0] for _ in range(PINGS)]
        # Every half of WATCHDOG_USEC, on a schedule that does not drift: one late ping does not move the
        # next, so their mean period holds even when a loaded machine makes single gaps long or short (the
        # bounds allow the last ping 2 s later than the first, or the first 2 s late).
        period = (pings[-1] - pings[0]) / (PINGS - 1)
        assert 0.5 * WATCHDOG_S / 2 < period < 1.5 * WATCHDOG_S / 2, [
            b - a for a, b in itertools.pairwise(pings)
        ]
        proc.send_signal(signal.SIGTERM)
        _, stopping = wait_for(notify_socket, "STOPPING=1", proc)
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
        proc.wait(timeout=10)
    rec = read_messages(the_recording(tmp_path))
    assert not rec.truncated
    assert rec.header is not None
    assert rec.header["config"]["robot_id"] == ROBOT  # type: ignore[index]
    assert rec.topic_counts[f"dishbot/{ROBOT}/state"] >= 1
    assert stopping.startswith("STOPPING=1")


@pytest.mark.slow
def test_daemon_killed_with_sigkill_leaves_a_recording_readable_to_about_a_second_before(
    tmp_path: Path, notify_socket: socket.socket
) -> None:
    """The writer flushes as the daemon runs (every ``flush_interval_s``, 0.5 s: a second at most is lost
    when the machine keeps up), and a kill loses nothing it had flushed. Both are seen on the file itself, not
    on the wall clock: a loaded machine runs the daemon's writer late by seconds."""
    proc = start_daemon(tmp_path, notify_socket)
    try:
        wait_for(notify_socket, "READY=1", proc)
        for _ in range(2):
            wait_for(notify_socket, "WATCHDOG=1", proc)
        path = the_recording(tmp_path)
        flushed = grown(path, grown(path, path.stat().st_size))  # two flushes while the daemon runs
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        proc.kill()
        proc.wait(timeout=10)
    rec = read_messages(path)
    assert rec.truncated
    assert rec.header is not None
    assert rec.topic_counts[f"dishbot/{ROBOT}/joints"] > 10
    assert rec.cut_at_byte is not None
    # Everything on disk before the kill is readable but the record being written (a chunk at most).
    assert rec.cut_at_byte > flushed - 2 * CHUNK_SIZE_BYTES
    assert rec.cut_after_ns is not None
    assert rec.start_ns is not None
    assert rec.cut_after_ns > rec.start_ns
    assert HEADER_TOPIC in rec.topic_counts
