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


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's worker reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In a pytest-xdist worker (``scripts/test.sh``: ``-n N --dist loadgroup``), the tests of a module that
    share a module- or class-scoped fixture (a recorded session, a booted systemd container, a pair of
    network namespaces) go into one group named after the module: they run on one worker, in file order,
    and the fixture is built once rather than once per worker. A test with its own ``xdist_group`` keeps it;
    the other tests spread over the workers one by one."""
    if not hasattr(config, "workerinput"):
        return
    for item in items:
        if not isinstance(item, pytest.Function) or item.get_closest_marker("xdist_group") is not None:
            continue
        scopes = {d.scope for defs in item._fixtureinfo.name2fixturedefs.values() for d in defs}
        if scopes & {"module", "class", "package"}:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.partition("::")[0]))


@pytest.fixture(autouse=True)
def _structlog_defaults() -> Iterator[None]:
    """CLI verbs point structlog at the stderr of the moment (a capture that closes after the test); later
    tests must not log into it."""
    yield
    structlog.reset_defaults()
