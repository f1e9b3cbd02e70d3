"""A pytest plugin for ``dishbot bench suite``: each test's outcome, time and ``slow`` marker, written as one
JSON document to ``--suite-times FILE`` when the session ends.

``bench suite`` loads it into the pytest it runs (``-p bench.suite_times``); it imports nothing but pytest, so
it changes neither what the suite imports nor how long it takes. A test's time is the sum of its setup, call
and teardown (its fixtures included), as ``--durations`` counts them. Under pytest-xdist (``-n N``) the
controller records what its workers report (a worker writes nothing), and a test's id loses the ``@group``
suffix ``--dist loadgroup`` gives it, so the records name the tests as a serial run does.
"""

from __future__ import annotations

import json
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
    if path is not None and not hasattr(config, "workerinput"):  # an xdist worker reports to its controller
        config.pluginmanager.register(_Recorder(Path(path)), "bench-suite-times")


class _Recorder:
    """Collects one record per test, phase by phase (setup, call, teardown), and writes them at the end."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.tests: dict[str, dict[str, Any]] = {}

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        nodeid = _ungrouped(report)
        entry = self.tests.setdefault(
            nodeid,
            {"nodeid": nodeid, "outcome": "passed", "time_s": 0.0, "slow": "slow" in report.keywords},
        )
        entry["time_s"] += report.duration
        entry["outcome"] = _outcome(report, entry["outcome"])

    def pytest_sessionfinish(self, exitstatus: int) -> None:
        doc = {"exit_status": int(exitstatus), "tests": list(self.tests.values())}
        self.path.write_text(json.dumps(doc), encoding="utf-8")


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
