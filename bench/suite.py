"""``dishbot bench suite``: run the test suite as ``scripts/test.sh`` runs it and say where its time goes.

The suite's pytest runs in a child process from the repository's root (its ``pyproject.toml`` options apply),
on ``scripts/test.sh``'s pytest-xdist workers (``--workers``, 0 for a serial run), with a small plugin
(``bench.suite_times``) recording each test's outcome, time (setup, call and teardown), CPU time and ``slow``
marker. Reported: the wall and CPU time of the run, the counts by outcome, the time of the tests not marked
slow (the inner loop, ``-m "not slow"``) beside that of the slow ones, the time by test directory, the slowest
tests and the tests that used the most CPU time. On a shared machine the CPU time and the load average say
how much of the wall time was other work; the tests' summed time over the wall time says how many ran at
once. Issue 22's target: the whole suite in <= 5 min on two cores.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cli.commands.output import format_table
from daemon.errors import UsageError

ROOT = Path(__file__).resolve().parent.parent
SLOWEST = 10
WORKERS = 3  # scripts/test.sh's default (DISHBOT_TEST_WORKERS)
TARGET_S = 300.0
OUTCOMES = ("passed", "failed", "error", "skipped", "xfailed", "xpassed")


@dataclass(frozen=True, slots=True)
class TimedTest:
    nodeid: str
    outcome: str
    time_s: float
    slow: bool
    cpu_s: float = 0.0  # the CPU time of the process that ran it and of the children it reaped

    @property
    def directory(self) -> str:
        """The test's folder under the suite (``tests/replay``); a test module at the top counts by itself."""
        path = Path(self.nodeid.partition("::")[0])
        parts = path.parts
        return "/".join(parts[:2]) if len(parts) > 2 else str(path)


@dataclass(frozen=True, slots=True)
class SuiteRun:
    command: tuple[str, ...]
    exit_status: int
    wall_s: float
    cpu_s: float
    load: tuple[float, float]  # one-minute load average when it started and when it ended
    tests: tuple[TimedTest, ...]
    workers: int = 0  # pytest-xdist workers; 0: serial


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "suite",
        help="run the test suite (scripts/test.sh's pytest): time, outcomes, slowest tests, time by folder",
        description=(
            "Run the suite's pytest from the repository root with a plugin that records each test's outcome "
            "and time, then print the wall and CPU time, the counts by outcome, the time of the tests not "
            "marked slow beside the slow ones, the time by test folder and the 10 slowest tests. "
            f"Target: the whole suite in <= {TARGET_S:.0f} s on two cores."
        ),
    )
    parser.add_argument(
        "-m",
        dest="marker",
        metavar="EXPR",
        help='only tests matching the marker expression (e.g. "not slow")',
    )
    parser.add_argument(
        "paths",
        nargs="*",
        metavar="PATH",
        help="test files or folders under the repository (default: tests/)",
    )
    parser.add_argument(
        "-n",
        "--workers",
        type=_workers,
        default=WORKERS,
        metavar="N",
        help=f"pytest-xdist workers, as scripts/test.sh runs them (default {WORKERS}; 0: serial)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of the tables")
    parser.set_defaults(handler=run)


def _workers(text: str) -> int:
    if not text.isdigit() or not 0 <= int(text) <= 64:
        raise argparse.ArgumentTypeError(f"{text!r}: choose 0 (serial) to 64 workers")
    return int(text)


def run(args: argparse.Namespace) -> int:
    if not (ROOT / "pyproject.toml").is_file() or not (ROOT / "tests").is_dir():
        raise UsageError(f"bench suite runs the tests of a source checkout; no tests/ beside {ROOT}")
    suite = run_suite(ROOT, marker=args.marker, paths=args.paths, workers=args.workers)
    print(as_json(suite) if args.json else as_tables(suite))
    return 0 if suite.exit_status == 0 else 1


def run_suite(
    root: Path, *, marker: str | None = None, paths: Sequence[str] = (), workers: int = WORKERS
) -> SuiteRun:
    """Run pytest on ``paths`` (default: the configured test paths) in ``root`` on ``workers`` pytest-xdist
    workers (0: serially, in the child itself); its output goes to stderr."""
    for p in paths:
        if not (root / p).exists():
            raise UsageError(f"{p}: no such test file or folder under {root}")
    if marker is not None:
        _check_marker(marker)
    with tempfile.TemporaryDirectory(prefix="dishbot-suite-") as tmp:
        times_file = Path(tmp) / "times.json"
        parallel = ("-n", str(workers), "--dist", "loadgroup") if workers else ()
        selection = [*parallel, *(() if marker is None else ("-m", marker)), *paths]
        command = [sys.executable, "-m", "pytest", "-p", "bench.suite_times", f"--suite-times={times_file}"]
        command += selection
        env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}  # as scripts/test.sh has it
        load_before = os.getloadavg()[0]
        cpu_before = _children_cpu_s()
        start = time.perf_counter()
        # pytest's report goes to file descriptor 2, so stdout carries only the bench's.
        proc = subprocess.run(command, cwd=root, env=env, stdout=2, check=False)
        wall = time.perf_counter() - start
        cpu = _children_cpu_s() - cpu_before
        # 3: pytest's internal error, 4: its usage error (a bad -m expression, say); 2: interrupted.
        if proc.returncode in (2, 3, 4) or not times_file.is_file():
            raise UsageError(f"pytest could not run the suite (exit {proc.returncode}): its message is above")
        doc: dict[str, Any] = json.loads(times_file.read_text(encoding="utf-8"))
    tests = tuple(
        TimedTest(t["nodeid"], t["outcome"], float(t["time_s"]), bool(t["slow"]), float(t.get("cpu_s", 0.0)))
        for t in doc["tests"]
    )
    load = (load_before, os.getloadavg()[0])
    return SuiteRun(("pytest", *selection), proc.returncode, wall, cpu, load, tests, workers)


def _check_marker(marker: str) -> None:
    """A ``-m`` expression pytest would refuse, refused here in one line (pytest-xdist's workers would each
    fail on it with a traceback)."""
    from _pytest.mark.expression import Expression  # pytest's own parser (the dev extra)

    try:
        Expression.compile(marker)
    except Exception as e:  # SyntaxError in pytest >= 8.4, its own ParseError before
        raise UsageError(f"-m {marker!r} is not a marker expression: {e}") from None


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def counts(tests: Sequence[TimedTest]) -> dict[str, int]:
    """How many tests ended in each outcome (every outcome listed, zeros included)."""
    found = dict.fromkeys(OUTCOMES, 0)
    for t in tests:
        found[t.outcome] = found.get(t.outcome, 0) + 1
    return found


def by_directory(tests: Sequence[TimedTest]) -> list[dict[str, Any]]:
    """Per test folder: its tests, failures and time, the most time first."""
    groups: dict[str, list[TimedTest]] = defaultdict(list)
    for t in tests:
        groups[t.directory].append(t)
    total = sum(t.time_s for t in tests) or 1.0
    rows = [
        {
            "directory": name,
            "tests": len(group),
            "failed": sum(t.outcome in ("failed", "error") for t in group),
            "slow_tests": sum(t.slow for t in group),
            "time_s": round(sum(t.time_s for t in group), 2),
            "share_pct": round(100 * sum(t.time_s for t in group) / total, 1),
        }
        for name, group in groups.items()
    ]
    return sorted(rows, key=lambda r: (-r["time_s"], r["directory"]))


def slowest(tests: Sequence[TimedTest], n: int = SLOWEST) -> list[TimedTest]:
    return sorted(tests, key=lambda t: (-t.time_s, t.nodeid))[:n]


def costliest(tests: Sequence[TimedTest], n: int = SLOWEST) -> list[TimedTest]:
    """The tests that used the most CPU time: on a shared machine, what a test costs rather than how long it
    waited."""
    return sorted(tests, key=lambda t: (-t.cpu_s, t.nodeid))[:n]


def summary(suite: SuiteRun) -> dict[str, Any]:
    """The run's figures, as the JSON document and the first table carry them."""
    tests = suite.tests
    fast = [t for t in tests if not t.slow]
    slow = [t for t in tests if t.slow]
    return {
        "command": shlex.join(suite.command),
        "exit_status": suite.exit_status,
        "wall_s": round(suite.wall_s, 1),
        "cpu_s": round(suite.cpu_s, 1),
        "load_start": round(suite.load[0], 2),
        "load_end": round(suite.load[1], 2),
        "workers": suite.workers,
        "tests": len(tests),
        **counts(tests),
        "tests_time_s": round(sum(t.time_s for t in tests), 1),
        "tests_cpu_s": round(sum(t.cpu_s for t in tests), 1),
        "outside_tests_s": round(suite.wall_s - sum(t.time_s for t in tests), 1),
        "tests_at_once": round(sum(t.time_s for t in tests) / suite.wall_s, 2) if suite.wall_s > 0 else 0.0,
        "not_slow_tests": len(fast),
        "not_slow_time_s": round(sum(t.time_s for t in fast), 1),
        "slow_tests": len(slow),
        "slow_time_s": round(sum(t.time_s for t in slow), 1),
        "target_s": TARGET_S,
    }


def as_json(suite: SuiteRun) -> str:
    doc = {
        "benchmark": "bench suite",
        **summary(suite),
        "by_directory": by_directory(suite.tests),
        "slowest": [
            {
                "test": t.nodeid,
                "outcome": t.outcome,
                "time_s": round(t.time_s, 2),
                "cpu_s": round(t.cpu_s, 2),
                "slow": t.slow,
            }
            for t in slowest(suite.tests)
        ],
        "costliest": [
            {"test": t.nodeid, "cpu_s": round(t.cpu_s, 2), "time_s": round(t.time_s, 2), "slow": t.slow}
            for t in costliest(suite.tests)
        ],
        # Every test, the costliest first: what a run's top 10 leaves out (a suite's top 30, a before/after).
        "by_test": [
            {
                "test": t.nodeid,
                "outcome": t.outcome,
                "cpu_s": round(t.cpu_s, 2),
                "time_s": round(t.time_s, 2),
                "slow": t.slow,
            }
            for t in costliest(suite.tests, len(suite.tests))
        ],
    }
    return json.dumps(doc, indent=2)


_LABELS = {
    "exit_status": "pytest exit status",
    "wall_s": "wall time, s",
    "cpu_s": "CPU time (user + system, every process), s",
    "load_start": "load average (1 min) at the start",
    "load_end": "load average (1 min) at the end",
    "workers": "pytest-xdist workers (0: serial)",
    "tests": "tests run",
    "tests_time_s": "sum of the tests' times, s",
    "tests_cpu_s": "sum of the tests' CPU times (their processes and reaped children), s",
    "outside_tests_s": "wall minus the tests' times, s (serial: start-up and collection; < 0 with workers)",
    "tests_at_once": "tests' time / wall time (tests running at once, on average)",
    "not_slow_tests": 'tests not marked slow (-m "not slow")',
    "not_slow_time_s": "their time, s",
    "slow_tests": "tests marked slow",
    "slow_time_s": "their time, s",
    "target_s": "target for the whole suite on two cores, s",
}


def as_tables(suite: SuiteRun) -> str:
    figures = summary(suite)
    command = figures.pop("command")
    rows = [[_LABELS.get(k, k), v] for k, v in figures.items()]
    folders = by_directory(suite.tests)
    return "\n\n".join(
        [
            f"bench suite: {command} (from the repository root)\n" + format_table(["figure", "value"], rows),
            "time by folder\n"
            + format_table(
                ["folder", "tests", "failed", "slow", "time_s", "share_%"],
                [
                    [r["directory"], r["tests"], r["failed"], r["slow_tests"], r["time_s"], r["share_pct"]]
                    for r in folders
                ],
            ),
            f"the {SLOWEST} slowest tests\n"
            + format_table(
                ["test", "outcome", "slow", "time_s", "cpu_s"],
                [
                    [t.nodeid, t.outcome, "yes" if t.slow else "", round(t.time_s, 2), round(t.cpu_s, 2)]
                    for t in slowest(suite.tests)
                ],
            ),
            f"the {SLOWEST} tests that used the most CPU time\n"
            + format_table(
                ["test", "outcome", "slow", "cpu_s", "time_s"],
                [
                    [t.nodeid, t.outcome, "yes" if t.slow else "", round(t.cpu_s, 2), round(t.time_s, 2)]
                    for t in costliest(suite.tests)
                ],
            ),
        ]
    )
