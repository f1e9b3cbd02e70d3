"""A pytest plugin for ``dishbot bench suite``: each test's outcome, time, CPU time and ``slow`` marker,
written as one JSON document to ``--suite-times FILE`` when the session ends.

``bench suite`` loads it into the pytest it runs (``-p bench.suite_times``); it imports nothing but pytest, so
it changes neither what the suite imports nor how long it takes. A test's time is the sum of its setup, call
and teardown (its fixtures included), as ``--durations`` counts them. Under pytest-xdist (``-n N``) the
controller records what its workers report (a worker writes nothing), and a test's id loses the ``@group``
suffix ``--dist loadgroup`` gives it, so the records name the tests as a serial run does.

A test's CPU time is measured in the process that runs it (a worker, or pytest itself when serial): the user
and system time of that process (all its threads), of the child processes it waited for (a daemon or a
``dishbot`` verb the test started and reaped) and of its live descendants (on Linux, from ``/proc``: the
planning workers a forkserver started, which the forkserver reaps, not the test), over its setup, call and
teardown. It travels to the controller in the report's ``user_properties``. On a shared machine it says what
a test costs where its wall time says how long it waited.
"""

from __future__ import annotations

import json
import os
import resource
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--suite-times",
        metavar="FILE",
        help="write each test's outcome, time and slow marker to FILE as JSON (dishbot bench suite)",
    )


def pytest_configure(config: pytest.Config) -> None:
    path = config.getoption("--suite-times")
    if path is None:
        return
    config.pluginmanager.register(_CpuMeter(), "bench-suite-cpu")
    if not hasattr(config, "workerinput"):  # an xdist worker reports to its controller
        config.pluginmanager.register(_Recorder(Path(path)), "bench-suite-times")


CPU_KEY = "bench_suite_cpu_s"


def _cpu_s() -> float:
    """This process's CPU time, that of the children it has waited for and that of its live descendants."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime + _descendants_cpu_s()


def _descendants_cpu_s() -> float:
    """The CPU time of this process's live descendants and of the children they waited for (``/proc``; 0
    where there is none). A descendant this process reaps moves into ``RUSAGE_CHILDREN`` with its time."""
    try:
        tick = os.sysconf("SC_CLK_TCK")
        ticks = 0
        for pid in _descendants(os.getpid()):
            try:
                stat = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
            except OSError:  # it ended meanwhile
                continue
            ticks += sum(int(v) for v in stat[11:15])  # utime, stime, cutime, cstime
        return ticks / tick
    except (OSError, ValueError):
        return 0.0


def _descendants(root: int) -> list[int]:
    found: list[int] = []
    todo = [root]
    while todo:
        pid = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{pid}/task")
        except OSError:
            continue
        for tid in tasks:
            try:
                kids = [int(k) for k in Path(f"/proc/{pid}/task/{tid}/children").read_text().split()]
            except OSError:
                continue
            found += kids
            todo += kids
    return found


class _CpuMeter:
    """Adds each phase's CPU time (setup, call, teardown) to its report's ``user_properties``."""

    def __init__(self) -> None:
        self.start = 0.0

    @pytest.hookimpl(wrapper=True, tryfirst=True)
    def pytest_runtest_setup(self) -> Iterator[None]:
        self.start = _cpu_s()
        return (yield)

    @pytest.hookimpl(wrapper=True, tryfirst=True)
    def pytest_runtest_call(self) -> Iterator[None]:
        self.start = _cpu_s()
        return (yield)

    @pytest.hookimpl(wrapper=True, tryfirst=True)
    def pytest_runtest_teardown(self) -> Iterator[None]:
        self.start = _cpu_s()
        return (yield)

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_makereport(self) -> Generator[None, pytest.TestReport, pytest.TestReport]:
        report = yield
        report.user_properties.append((CPU_KEY, round(_cpu_s() - self.start, 4)))
        return report


class _Recorder:
    """Collects one record per test, phase by phase (setup, call, teardown), and writes them at the end."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.tests: dict[str, dict[str, Any]] = {}

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        nodeid = _ungrouped(report)
        entry = self.tests.setdefault(
            nodeid,
            {
                "nodeid": nodeid,
                "outcome": "passed",
                "time_s": 0.0,
                "cpu_s": 0.0,
                "slow": "slow" in report.keywords,
            },
        )
        entry["time_s"] += report.duration
        entry["cpu_s"] += _phase_cpu_s(report)
        entry["outcome"] = _outcome(report, entry["outcome"])

    def pytest_sessionfinish(self, exitstatus: int) -> None:
        doc = {"exit_status": int(exitstatus), "tests": list(self.tests.values())}
        self.path.write_text(json.dumps(doc), encoding="utf-8")


def _phase_cpu_s(report: pytest.TestReport) -> float:
    """The phase's CPU time, as ``_CpuMeter`` put it in the report (0 from a worker without the meter)."""
    found = [v for k, v in report.user_properties if k == CPU_KEY]
    return float(found[-1]) if found and isinstance(found[-1], (int, float)) else 0.0


def _ungrouped(report: pytest.TestReport) -> str:
    """The test's id without the ``@group`` that pytest-xdist's ``--dist loadgroup`` appends to the id of a
    test marked ``xdist_group`` (group names hold no ``@``)."""
    if "xdist_group" in report.keywords and "@" in report.nodeid:
        return report.nodeid.rpartition("@")[0]
    return report.nodeid


def _outcome(report: pytest.TestReport, so_far: str) -> str:
    """The test's outcome after this phase: a failure in setup or teardown is an error (as pytest has it)."""
    if hasattr(report, "wasxfail"):
        return "xfailed" if report.skipped else "xpassed"
    if report.skipped:
        return "skipped"
    if report.failed:
        return "failed" if report.when == "call" else "error"
    return so_far
