"""Fixtures for daemon tests: structlog reset after each test (and the harness's ``free_port``)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import structlog

from tests.fakes.daemon import free_port

__all__ = ["free_port"]  # where the daemon tests have long taken it from; it lives with the harness


@pytest.fixture(autouse=True)
def _structlog_defaults() -> Iterator[None]:
    """``dishbot run``/``bench`` point structlog at the stderr of the moment; undo it after each test."""
    yield
    structlog.reset_defaults()
