"""Fixtures for the perception tests: the default cell layout, and structlog restored after each test."""

from __future__ import annotations

import tomllib
from collections.abc import Iterator
from importlib import resources

import pytest
import structlog

from description.cell import SceneLayout


def default_layout() -> SceneLayout:
    """The cell of the embedded default config."""
    text = resources.files("daemon").joinpath("default_config.toml").read_text(encoding="utf-8")
    data = tomllib.loads(text)
    return SceneLayout.from_config(data["cell"], data["camera"])


@pytest.fixture(scope="session")
def layout() -> SceneLayout:
    return default_layout()


@pytest.fixture(autouse=True)
def _restore_structlog() -> Iterator[None]:
    """The CLI commands point structlog at the stderr of the moment (a capture that closes after the test);
    later tests must not log into it."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)
