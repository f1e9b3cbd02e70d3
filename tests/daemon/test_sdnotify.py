"""sd_notify speaks systemd's datagram protocol to a real unix socket, and is silent outside systemd."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
from structlog.testing import capture_logs

from daemon.sdnotify import SdNotifier


@pytest.fixture
def systemd_socket(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket standing in for systemd's notify socket, bound at a path."""
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(2.0)
    yield sock, str(path)
    sock.close()


def received(sock: socket.socket) -> str:
    return sock.recv(4096).decode()


def test_lifecycle_messages_arrive_as_systemd_expects(systemd_socket: tuple[socket.socket, str]) -> None:
    sock, path = systemd_socket
    with SdNotifier.from_env({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "4000000"}) as notifier:
        assert notifier.enabled
        assert notifier.watchdog_interval_s == 4.0
        assert notifier.ready(status="idle, 0 mugs")
        assert received(sock) == "READY=1\nSTATUS=idle, 0 mugs"
        assert notifier.watchdog()
        assert received(sock) == "WATCHDOG=1"
        assert notifier.status("placing mug 3 of 12\nline two")
        assert received(sock) == "STATUS=placing mug 3 of 12 line two"
        assert notifier.extend_timeout(12.5)
        assert received(sock) == "EXTEND_TIMEOUT_USEC=12500000"
        assert notifier.stopping()
        assert received(sock) == "STOPPING=1"


def test_abstract_namespace_socket_is_reached_through_the_at_sign() -> None:
    name = f"dishbot-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        with SdNotifier.from_env({"NOTIFY_SOCKET": "@" + name}) as notifier:
            assert notifier.ready()
            assert received(sock) == "READY=1"
    finally:
        sock.close()


def test_outside_systemd_every_call_is_a_silent_no_op() -> None:
    notifier = SdNotifier.from_env({})
    assert not notifier.enabled
    assert notifier.watchdog_interval_s is None
    assert not notifier.ready()
    assert not notifier.watchdog()
    assert not notifier.stopping()


@pytest.mark.parametrize(
    ("env", "interval"),
    [
        ({"WATCHDOG_USEC": "3000000", "WATCHDOG_PID": "4242"}, 3.0),
        ({"WATCHDOG_USEC": "3000000", "WATCHDOG_PID": "999"}, None),
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({"WATCHDOG_USEC": "-5"}, None),
        ({}, None),
    ],
)
def test_watchdog_applies_only_to_the_named_process(env: dict[str, str], interval: float | None) -> None:
    assert SdNotifier.from_env(env, pid=4242).watchdog_interval_s == interval


def test_a_vanished_socket_is_logged_once_and_recovery_once(tmp_path: Path) -> None:
    path = tmp_path / "gone.sock"
    with SdNotifier(str(path)) as notifier, capture_logs() as logs:
        assert not notifier.watchdog()
        assert not notifier.watchdog()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(str(path))
        try:
            assert notifier.watchdog()
            assert sock.recv(64) == b"WATCHDOG=1"
        finally:
            sock.close()
    assert [e["event"] for e in logs] == ["sd_notify_failed", "sd_notify_recovered"]


def test_a_full_systemd_queue_never_blocks_the_sender(systemd_socket: tuple[socket.socket, str]) -> None:
    _, path = systemd_socket
    with SdNotifier(path) as notifier:
        results = [notifier.watchdog() for _ in range(5000)]
    assert results[0]
    assert not all(results)  # nobody reads: the socket's queue fills and sends are refused, not waited on
