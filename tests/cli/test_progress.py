"""Progress lines on stderr: mug k of N for a ``--once`` job, case k of N for a bench, elapsed wall time,
simulated time and an estimate of the time left; nothing when not enabled; a closed stderr silences them."""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cli.commands.run import MugProgress
from cli.progress import Progress
from tests.daemon.conftest import free_port
from tests.fakes.counter import mugs_file


class Wall:
    """A wall clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_steps_say_k_of_n_elapsed_and_the_time_left_from_the_pace_since_the_first_step() -> None:
    wall, out = Wall(), io.StringIO()
    progress = Progress("bench placement", 3, stream=out, wall=wall)
    wall.now += 20.0  # set-up: not counted in the pace
    progress.next("dataset 1: bh")
    wall.now += 4.0
    progress.next("dataset 1: sa")
    wall.now += 6.0
    progress.next()
    progress.done()
    assert out.getvalue().splitlines() == [
        "bench placement: case 1 of 3 (dataset 1: bh), elapsed 20.0 s",
        "bench placement: case 2 of 3 (dataset 1: sa), elapsed 24.0 s, about 8 s left",
        "bench placement: case 3 of 3, elapsed 30.0 s, about 5 s left",
        "bench placement: done, elapsed 30.0 s",
    ]


def test_a_progress_not_enabled_prints_nothing() -> None:
    out = io.StringIO()
    progress = Progress("bench placement", 2, enabled=False, stream=out)
    progress.next("x")
    progress.done()
    assert out.getvalue() == ""
    assert progress.lines == []


def test_a_closed_stderr_silences_the_progress_instead_of_failing_the_work() -> None:
    out = io.StringIO()
    out.close()
    progress = Progress("dishbot run", 2, stream=out)
    progress.next("m1")  # no ValueError
    assert progress.enabled is False


def state(
    name: str, t: float, *, placed: int = 0, failed: int = 0, planned: int = 0, mug: str | None = None
) -> dict[str, object]:
    return {
        "state": name,
        "t": t,
        "mugs_total": 3,
        "mugs_planned": planned,
        "mugs_placed": placed,
        "mugs_failed": failed,
        "current_mug": mug,
    }


def test_a_once_job_says_mug_k_of_n_as_each_mug_begins_and_how_it_ended() -> None:
    wall, out = Wall(), io.StringIO()
    tap = MugProgress(Progress("dishbot run", 0, unit="mug", stream=out, wall=wall), simulated=True)
    stream = [
        state("idle", 1000.0),
        state("detect", 1000.0),
        state("plan", 1001.0),
        state("side_grasp.approach", 1002.0, planned=2, mug="m3"),
        state("side_grasp.lift", 1005.0, planned=2, mug="m3"),  # the same mug: no new line
        state("place.release", 1020.0, planned=2, mug="m3"),
        state("side_grasp.approach", 1030.0, planned=2, placed=1, mug="m1"),
        state("done", 1060.0, planned=2, placed=1, failed=1),
        state("done", 1061.0, planned=2, placed=1, failed=1),  # repeated at the state rate: said once
    ]
    for payload in stream:
        wall.now += 1.0
        tap("joints", {"t": 0.0})  # other topics are not looked at
        tap("state", payload)
    assert out.getvalue().splitlines() == [
        "dishbot run: mug 1 of 2 (m3), elapsed 4.0 s, simulated 2.0 s",
        "dishbot run: mug 2 of 2 (m1), elapsed 7.0 s, simulated 30.0 s, about 3 s left",
        "dishbot run: done (done: 1 of 2 placed), elapsed 8.0 s, simulated 60.0 s",
    ]


def test_on_the_wall_clock_no_simulated_time_is_shown() -> None:
    out = io.StringIO()
    tap = MugProgress(Progress("dishbot run", 0, unit="mug", stream=out, wall=Wall()), simulated=False)
    tap("state", state("idle", 5.0))
    tap("state", state("side_grasp.approach", 9.0, planned=3, mug="m2"))
    assert out.getvalue() == "dishbot run: mug 1 of 3 (m2), elapsed 0.0 s\n"


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_once_run_prints_mug_k_of_n_on_stderr_and_nothing_of_it_on_stdout(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "cli.main", "run", "--sim", "--world", "kinematic", "--once"]
    cmd += ["--listen", f"tcp/127.0.0.1:{free_port()}", "--record-dir", str(tmp_path)]
    cmd += ["--mugs", str(mugs_file(tmp_path, 2))]  # two mugs show k of N counting up as the dataset does
    done = subprocess.run(
        cmd, capture_output=True, text=True, timeout=540, cwd=Path(__file__).parents[2], check=False
    )
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("dishbot run: ")]
    step = r"dishbot run: mug (\d+) of (\d+) \((m\d+)\), elapsed [\d.]+ s, simulated [\d.]+ s.*"
    steps = [re.fullmatch(step, line) for line in lines[:-1]]
    assert len(steps) >= 2
    assert all(steps), lines
    assert [int(m.group(1)) for m in steps if m] == list(range(1, len(steps) + 1))
    summary = done.stdout.splitlines()
    planned = int(re.search(r"planned (\d+)", done.stdout).group(1))  # type: ignore[union-attr]
    assert {int(m.group(2)) for m in steps if m} == {planned}
    end = r"dishbot run: done \(done: \d+ of \d+ placed\), elapsed [\d.]+ s, simulated [\d.]+ s"
    assert re.fullmatch(end, lines[-1])
    assert not any(line.startswith("dishbot run: ") for line in summary)
