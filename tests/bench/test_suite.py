"""`dishbot bench suite`: the plugin records every test's outcome, time, CPU time and slow marker; the bench
runs a suite in a child pytest and reports its counts, folders, slowest and costliest tests."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import textwrap
from pathlib import Path

import pytest

from bench.suite import (
    WORKERS,
    SuiteRun,
    TimedTest,
    as_json,
    as_tables,
    by_directory,
    costliest,
    counts,
    run_suite,
    slowest,
)
from cli.main import main
from daemon.errors import UsageError

# A small suite with one test of each outcome, a slow one, and a test module at the top.
SUITE = {
    "tests/alpha/test_outcomes.py": """
        import time
        import pytest

        @pytest.fixture
        def broken():
            raise RuntimeError("no fixture")

        def test_passes():
            time.sleep(0.05)

        def test_fails():
            assert 1 == 2

        def test_skips():
            pytest.skip("not here")

        @pytest.mark.xfail(strict=True)
        def test_xfails():
            assert False

        def test_errors(broken):
            pass

        @pytest.mark.slow
        def test_slow_passes():
            start = time.process_time()  # 0.1 s of CPU time, however loaded the machine
            while time.process_time() - start < 0.1:
                pass
    """,
    "tests/beta/deeper/test_more.py": """
        def test_one():
            pass

        def test_two():
            pass
    """,
    "tests/test_top.py": """
        def test_top():
            pass
    """,
}


def write_suite(root: Path) -> None:
    (root / "pyproject.toml").write_text(
        '[tool.pytest.ini_options]\ntestpaths = ["tests"]\nmarkers = ["slow: slow"]\n', encoding="utf-8"
    )
    for name, text in SUITE.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text), encoding="utf-8")


def test_the_plugin_records_each_tests_outcome_time_and_slow_marker(pytester: pytest.Pytester) -> None:
    write_suite(pytester.path)
    out = pytester.path / "times.json"
    result = pytester.runpytest_inprocess("-p", "bench.suite_times", f"--suite-times={out}")
    result.assert_outcomes(passed=5, failed=1, skipped=1, xfailed=1, errors=1)
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["exit_status"] == 1
    tests = {t["nodeid"].rpartition("::")[2]: t for t in doc["tests"]}
    assert {name: t["outcome"] for name, t in tests.items()} == {
        "test_passes": "passed",
        "test_fails": "failed",
        "test_skips": "skipped",
        "test_xfails": "xfailed",
        "test_errors": "error",
        "test_slow_passes": "passed",
        "test_one": "passed",
        "test_two": "passed",
        "test_top": "passed",
    }
    assert [name for name, t in tests.items() if t["slow"]] == ["test_slow_passes"]
    assert tests["test_passes"]["time_s"] >= 0.05  # its call slept that long
    # CPU time: the busy test's 0.1 s counts, a sleep hardly (the process's CPU time over its phases).
    assert tests["test_slow_passes"]["cpu_s"] >= 0.1
    assert 0 <= tests["test_passes"]["cpu_s"] < tests["test_slow_passes"]["cpu_s"]
    assert tests["test_passes"]["nodeid"] == "tests/alpha/test_outcomes.py::test_passes"


BUSY_CHILD = """
import subprocess, sys
from pathlib import Path

BURN = (
    "import time\\nt = time.process_time()\\nwhile time.process_time() - t < 0.2: pass\\n"
    "print('burnt', flush=True)\\ntime.sleep(60)"
)

def test_leaves_a_busy_child():
    child = subprocess.Popen([sys.executable, "-c", BURN], stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline() == "burnt\\n"
    Path("child.pid").write_text(str(child.pid))
"""


def test_a_tests_cpu_time_counts_the_processes_it_left_running(pytester: pytest.Pytester) -> None:
    """A child the test did not wait for (as a forkserver's planning worker, reaped by the forkserver) still
    counts: its 0.2 s of CPU time are in the test's."""
    pytester.makepyfile(test_child=BUSY_CHILD)
    out = pytester.path / "times.json"
    try:
        result = pytester.runpytest_inprocess("-p", "bench.suite_times", f"--suite-times={out}")
    finally:
        pid_file = pytester.path / "child.pid"
        if pid_file.is_file():
            pid = int(pid_file.read_text())
            os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
    result.assert_outcomes(passed=1)
    (test,) = json.loads(out.read_text(encoding="utf-8"))["tests"]
    assert test["cpu_s"] >= 0.2


def test_without_the_option_the_plugin_writes_nothing(pytester: pytest.Pytester) -> None:
    write_suite(pytester.path)
    pytester.runpytest_inprocess("-p", "bench.suite_times", "tests/test_top.py").assert_outcomes(passed=1)
    assert sorted(p.name for p in pytester.path.iterdir() if not p.name.startswith(".")) == [
        "pyproject.toml",
        "tests",
    ]


def _t(
    nodeid: str, time_s: float, outcome: str = "passed", *, slow: bool = False, cpu_s: float = 0.0
) -> TimedTest:
    return TimedTest(nodeid, outcome, time_s, slow, cpu_s)


RUN = SuiteRun(
    ("pytest", "-m", "not slow"),
    1,
    10.0,
    4.0,
    (1.5, 2.5),
    (
        _t("tests/replay/test_a.py::test_1", 3.0, slow=True, cpu_s=0.5),  # waits, mostly
        _t("tests/replay/test_a.py::test_2", 1.0, "failed", cpu_s=0.9),
        _t("tests/planning/placement/test_b.py::test_3", 2.0),
        _t("tests/planning/test_c.py::test_4[x-y]", 0.5, "error"),
        _t("tests/test_readme.py::test_5", 1.5, "skipped"),
    ),
)


def test_tests_count_by_outcome_and_time_by_their_top_folder() -> None:
    assert counts(RUN.tests) == {
        "passed": 2,
        "failed": 1,
        "error": 1,
        "skipped": 1,
        "xfailed": 0,
        "xpassed": 0,
    }
    assert by_directory(RUN.tests) == [
        {
            "directory": "tests/replay",
            "tests": 2,
            "failed": 1,
            "slow_tests": 1,
            "time_s": 4.0,
            "share_pct": 50.0,
        },
        {
            "directory": "tests/planning",
            "tests": 2,
            "failed": 1,
            "slow_tests": 0,
            "time_s": 2.5,
            "share_pct": 31.2,
        },
        {
            "directory": "tests/test_readme.py",
            "tests": 1,
            "failed": 0,
            "slow_tests": 0,
            "time_s": 1.5,
            "share_pct": 18.8,
        },
    ]
    assert [t.nodeid.rpartition("::")[2] for t in slowest(RUN.tests, 3)] == ["test_1", "test_3", "test_5"]


def test_the_report_gives_the_not_slow_time_beside_the_slow_and_what_lies_outside_the_tests() -> None:
    doc = json.loads(as_json(RUN))
    assert doc["benchmark"] == "bench suite"
    assert doc["command"] == "pytest -m 'not slow'"
    assert (doc["tests"], doc["passed"], doc["failed"], doc["error"], doc["skipped"]) == (5, 2, 1, 1, 1)
    assert (doc["not_slow_tests"], doc["not_slow_time_s"]) == (4, 5.0)
    assert (doc["slow_tests"], doc["slow_time_s"]) == (1, 3.0)
    assert (doc["tests_time_s"], doc["outside_tests_s"]) == (8.0, 2.0)
    assert (doc["wall_s"], doc["cpu_s"], doc["load_start"], doc["load_end"]) == (10.0, 4.0, 1.5, 2.5)
    assert [s["test"] for s in doc["slowest"]][:1] == ["tests/replay/test_a.py::test_1"]
    assert doc["tests_cpu_s"] == 1.4
    assert [(s["test"], s["cpu_s"]) for s in doc["costliest"]][:2] == [
        ("tests/replay/test_a.py::test_2", 0.9),
        ("tests/replay/test_a.py::test_1", 0.5),
    ]
    assert [t.nodeid for t in costliest(RUN.tests, 1)] == ["tests/replay/test_a.py::test_2"]
    # Every test, the costliest first, with its outcome.
    assert [(s["test"], s["cpu_s"]) for s in doc["by_test"]] == [
        (t.nodeid, round(t.cpu_s, 2)) for t in costliest(RUN.tests, len(RUN.tests))
    ]
    assert {s["outcome"] for s in doc["by_test"]} == {t.outcome for t in RUN.tests}
    assert len(doc["by_test"]) == doc["tests"] == 5
    text = as_tables(RUN)
    assert text.startswith("bench suite: pytest -m 'not slow' (from the repository root)\n")
    assert "time by folder" in text
    assert "the 10 slowest tests" in text
    assert "the 10 tests that used the most CPU time" in text


def test_a_path_that_is_not_there_is_refused_before_anything_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "suite", "tests/no_such_folder"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dishbot bench: error: tests/no_such_folder: no such test file or folder under ")


def test_the_bench_runs_as_many_workers_as_scripts_test_sh() -> None:
    script = (Path(__file__).parents[2] / "scripts" / "test.sh").read_text(encoding="utf-8")
    assert f'workers="${{DISHBOT_TEST_WORKERS:-{WORKERS}}}"' in script


@pytest.mark.parametrize("workers", ["x", "-1", "65"])
def test_a_worker_count_out_of_range_is_a_usage_error(
    workers: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["bench", "suite", "--workers", workers])
    assert exit_info.value.code == 2
    assert f"argument -n/--workers: {workers!r}: choose 0 (serial) to 64 workers" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_suite_runs_the_suite_in_a_child_pytest_and_reports_it(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    write_suite(tmp_path)
    # A group of two under --dist loadgroup: the records name its tests without xdist's "@group" suffix.
    (tmp_path / "tests" / "test_grouped.py").write_text(
        "import time\nimport pytest\n\n@pytest.mark.xdist_group('pair')\ndef test_g1():\n"
        "    start = time.process_time()\n    while time.process_time() - start < 0.1:\n        pass\n\n"
        "@pytest.mark.xdist_group('pair')\ndef test_g2():\n    pass\n",
        encoding="utf-8",
    )
    run = run_suite(tmp_path, marker="not slow", workers=2)
    assert run.exit_status == 1  # one failure, one error
    assert run.command == ("pytest", "-n", "2", "--dist", "loadgroup", "-m", "not slow")
    assert (run.workers, json.loads(as_json(run))["workers"]) == (2, 2)
    assert sorted(t.nodeid for t in run.tests if "grouped" in t.nodeid) == [
        "tests/test_grouped.py::test_g1",
        "tests/test_grouped.py::test_g2",
    ]
    assert counts(run.tests) == {
        "passed": 6,
        "failed": 1,
        "error": 1,
        "skipped": 1,
        "xfailed": 1,
        "xpassed": 0,
    }
    assert not any(t.slow for t in run.tests)
    assert [r["directory"] for r in sorted(by_directory(run.tests), key=lambda r: r["directory"])] == [
        "tests/alpha",
        "tests/beta",
        "tests/test_grouped.py",
        "tests/test_top.py",
    ]
    assert run.cpu_s > 0  # the workers are children of the child: their CPU time counts
    # Each test's CPU time comes from the worker that ran it (test_g1 keeps its worker busy for 0.1 s).
    assert [t.cpu_s >= 0.1 for t in run.tests if t.nodeid.endswith("::test_g1")] == [True]
    assert all(t.cpu_s >= 0 for t in run.tests)
    out, err = capfd.readouterr()
    assert out == ""  # pytest's own output goes to stderr: stdout is the report's
    assert "1 failed" in err


def test_a_marker_expression_pytest_refuses_is_a_usage_error(tmp_path: Path) -> None:
    write_suite(tmp_path)
    with pytest.raises(UsageError) as info:
        run_suite(tmp_path, marker="not (slow")
    assert str(info.value).startswith("-m 'not (slow' is not a marker expression: ")
    assert "right parenthesis" in str(info.value)


@pytest.mark.slow
def test_a_suite_pytest_cannot_start_is_a_usage_error(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    write_suite(tmp_path)
    (tmp_path / "tests" / "conftest.py").write_text(
        "raise RuntimeError('broken conftest')\n", encoding="utf-8"
    )
    with pytest.raises(
        UsageError, match=r"^pytest could not run the suite \(exit 4\): its message is above$"
    ):
        run_suite(tmp_path, workers=0)
    assert "broken conftest" in capfd.readouterr().err
