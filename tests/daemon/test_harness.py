"""The daemon harness (``tests.fakes.daemon``) refuses to start a daemon for a test not marked slow, so the
fast inner loop (``-m "not slow"``) never starts one; the guard (``tests.fakes.slow_guard``) knows the test
from its setup (a fixture that starts a daemon) to its end."""

from __future__ import annotations

import pytest

pytest_plugins = ["pytester"]

GUARDED = """
import pytest

from tests.fakes.slow_guard import refuse_unless_slow


@pytest.fixture
def started() -> None:
    refuse_unless_slow("a daemon")


def test_fast() -> None:
    refuse_unless_slow("a daemon")


@pytest.mark.slow
def test_slow() -> None:
    refuse_unless_slow("a daemon")


def test_fast_through_a_fixture(started: None) -> None:
    pass


@pytest.mark.slow
class TestSlowClass:
    def test_in_a_slow_class(self, started: None) -> None:
        pass
"""


def test_a_test_that_starts_a_daemon_must_be_marked_slow(pytester: pytest.Pytester) -> None:
    pytester.makeini("[pytest]\nmarkers = slow: starts something slow\n")
    pytester.makepyfile(test_guarded=GUARDED)
    result = pytester.runpytest("-p", "tests.fakes.slow_guard", "-q")
    result.assert_outcomes(passed=2, failed=1, errors=1)
    result.stdout.fnmatch_lines(
        [
            "*AssertionError: test_guarded.py::test_fast starts a daemon: mark it @pytest.mark.slow "
            "(the fast loop leaves it out)",
        ]
    )
    result.stdout.fnmatch_lines(["*ERROR at setup of test_fast_through_a_fixture*"])


def test_outside_a_test_the_guard_lets_a_daemon_start() -> None:
    from tests.fakes.slow_guard import _running, refuse_unless_slow

    saved = list(_running)
    _running.clear()
    try:
        refuse_unless_slow("a daemon")  # a script or a REPL: nothing to refuse
    finally:
        _running[:] = saved
