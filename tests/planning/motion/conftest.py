"""Fixtures shared by these tests: the CLI configures structlog globally, so every test starts and ends
with structlog's defaults (other areas' tests capture log events)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import structlog


@pytest.fixture(autouse=True)
def _structlog_defaults() -> Iterator[None]:
    structlog.reset_defaults()
    yield
    structlog.reset_defaults()
