"""tests/conftest.py under pytest-xdist: the costliest work goes out first (by the times pytest's cache kept
from the runs before, else slow before the rest), a module sharing a module fixture stays one piece in file
order, and each run leaves its tests' times in the cache for the next."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Each test notes its name in ran.txt as it runs: one worker runs the work units in the order handed out.
SUITE = """
import pytest
from pathlib import Path

def note(name):
    with Path("ran.txt").open("a") as f:
        f.write(name + "\\n")

@pytest.fixture(scope="module")
def shared():
    return "built once"

def test_fast():
    note("fast")

@pytest.mark.slow
def test_slow():
    note("slow")

def test_known():
    note("known")

def test_shared_1(shared):
    note("shared_1")

def test_shared_2(shared):
    note("shared_2")
"""


@pytest.mark.slow  # pytest-xdist starts a worker process
def test_the_costliest_work_goes_out_first_and_the_times_are_kept(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the worker imports tests.conftest from this checkout
    pytester.makeini("[pytest]\nmarkers =\n    slow: slow\n")
    pytester.makeconftest("from tests.conftest import pytest_collection_modifyitems, pytest_configure\n")
    pytester.makepyfile(test_order=SUITE)
    cache = pytester.path / ".pytest_cache" / "v" / "dishbot"
    cache.mkdir(parents=True)
    # The run before: test_known took 50 s, the module's pair 20 s together, test_slow is new (10 s).
    (cache / "durations").write_text(
        json.dumps(
            {
                "test_order.py::test_known": 50.0,
                "test_order.py::test_shared_1": 12.0,
                "test_order.py::test_shared_2": 8.0,
                "test_order.py::test_fast": 0.5,
            }
        )
    )
    result = pytester.runpytest_subprocess("-n", "1", "--dist", "loadgroup")
    result.assert_outcomes(passed=5)
    ran = (pytester.path / "ran.txt").read_text().split()
    assert ran == ["known", "shared_1", "shared_2", "slow", "fast"]
    kept = json.loads((cache / "durations").read_text())
    assert sorted(kept) == [
        f"test_order.py::test_{n}" for n in ("fast", "known", "shared_1", "shared_2", "slow")
    ]
    assert kept["test_order.py::test_known"] < 50.0  # this run's time replaced the one before


@pytest.mark.slow
def test_without_times_a_slow_test_goes_out_before_the_others(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    pytester.makeini("[pytest]\nmarkers =\n    slow: slow\n")
    pytester.makeconftest("from tests.conftest import pytest_collection_modifyitems, pytest_configure\n")
    pytester.makepyfile(test_order=SUITE)
    result = pytester.runpytest_subprocess("-n", "1", "--dist", "loadgroup")
    result.assert_outcomes(passed=5)
    # test_slow counts 10 s; the pair 0.2 s; the rest 0.1 s each, in file order.
    assert (pytester.path / "ran.txt").read_text().split() == [
        "slow",
        "shared_1",
        "shared_2",
        "fast",
        "known",
    ]


# Six tests sharing a module fixture that notes each time it is built.
SHARED = """
import pytest
from pathlib import Path

@pytest.fixture(scope="module")
def shared():
    with Path("built.txt").open("a") as f:
        f.write("built\\n")

@pytest.mark.parametrize("n", range(6))
def test_shared(shared, n):
    pass
"""


@pytest.mark.slow
def test_a_module_fixture_is_built_once_on_two_workers(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the group, pytest-xdist hands the six tests out three and three and both workers build the
    fixture (as pytest 9.2 with pytest-xdist 3.8 did: the group id was lost)."""
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    pytester.makeconftest("from tests.conftest import pytest_collection_modifyitems, pytest_configure\n")
    pytester.makepyfile(test_shared=SHARED)
    result = pytester.runpytest_subprocess("-n", "2", "--dist", "loadgroup", "-v")
    result.assert_outcomes(passed=6)
    assert (pytester.path / "built.txt").read_text().split() == ["built"]
    result.stdout.fnmatch_lines(["*test_shared.py::test_shared?0?@test_shared.py*"])
