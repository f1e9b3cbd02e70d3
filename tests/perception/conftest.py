"""Fixtures for the perception tests: the default cell layout, and structlog restored after each test."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import structlog

from daemon.config import load_config
from description.cell import CellLayout


def default_layout() -> CellLayout:
    """The cell of the embedded default config."""
    return load_config().cell


@pytest.fixture(scope="session")
def layout() -> CellLayout:
    return default_layout()


@pytest.fixture(autouse=True)
def _restore_structlog() -> Iterator[None]:
    """The CLI commands point structlog at the stderr of the moment (a capture that closes after the test);
    later tests must not log into it."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)
