"""Shared fixtures for the dishbot test suite."""

from __future__ import annotations

import os
from collections.abc import Iterator
from importlib.metadata import entry_points

import pytest
import structlog

# pytester: the tests of the pytest plugin dishbot ships run pytest inside pytest. The plugin itself comes
# with the installed package (entry point pytest11 "dishbot"); an install older than the entry point gets
# it by name.
pytest_plugins = ["pytester", "tests.fakes.slow_guard"]
if not any(e.name == "dishbot" for e in entry_points(group="pytest11")):
    pytest_plugins.append("replay.pytest_plugin")

# MuJoCo renders offscreen without a GPU through EGL (Mesa llvmpipe); set before any mujoco import.
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(autouse=True)
def _structlog_defaults() -> Iterator[None]:
    """CLI verbs point structlog at the stderr of the moment (a capture that closes after the test); later
    tests must not log into it."""
    yield
    structlog.reset_defaults()
