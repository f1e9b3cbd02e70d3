"""Fixtures for daemon tests: free loopback ports; structlog reset after each test."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest
import structlog


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@pytest.fixture(autouse=True)
def _structlog_defaults() -> Iterator[None]:
    """``dishbot run``/``bench`` point structlog at the stderr of the moment; undo it after each test."""
    yield
    structlog.reset_defaults()
