"""A pytest plugin (registered in ``tests/conftest.py``) that knows which test is running, so a harness that
starts something slow (a daemon) can refuse to for a test not marked ``@pytest.mark.slow``: the fast inner
loop (``-m "not slow"``) must not start one. Imports nothing but pytest, so it costs no start-up time."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

_running: list[pytest.Item] = []  # the test being set up or run


def refuse_unless_slow(what: str) -> None:
    """Fail the running test when it is not marked slow; ``what`` it starts goes in the message."""
    if _running and _running[-1].get_closest_marker("slow") is None:
        raise AssertionError(
            f"{_running[-1].nodeid} starts {what}: mark it @pytest.mark.slow (the fast loop leaves it out)"
        )


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    """The test's fixtures (one may start a daemon) run while it is known."""
    _running.append(item)
    try:
        return (yield)
    finally:
        _running.pop()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    _running.append(item)
    try:
        return (yield)
    finally:
        _running.pop()
