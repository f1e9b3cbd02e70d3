"""``dishbot bench replay --memory``: bad flags are refused in one clear line before anything is recorded,
and the measuring process reports a replay's resident memory (its figures are in docs/recording.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.replay_memory import CHILD, cases, measure
from cli.main import main

RIG_RECORDING = Path(__file__).parents[1] / "data" / "rig-2mugs-job.mcap"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--memory", "--paused-s", "0"], "--paused-s 0 is out of range; allowed [1, 14400]"),
        (["--memory", "--paused-s", "nan"], "--paused-s nan is out of range; allowed [1, 14400]"),
        (["--memory", "--paused-s", "20000"], "--paused-s 20000 is out of range; allowed [1, 14400]"),
        (["--paused-s", "60"], "--paused-s and --memory-mujoco go with --memory"),
        (["--memory-mujoco"], "--paused-s and --memory-mujoco go with --memory"),
        (["--memory", "--rig", "1"], "--memory records its own jobs; leave out --sessions and --rig"),
        (
            ["--memory", "--sessions", "1,0,0"],
            "--memory records its own jobs; leave out --sessions and --rig",
        ),
    ],
)
def test_bad_memory_flags_exit_2_with_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "replay", *argv]) == 2
    assert capsys.readouterr().err == f"dishbot bench: error: {message}\n"


def test_the_memory_cases_are_an_ordinary_job_and_a_paused_one() -> None:
    assert [(c.world, c.paused_s) for c in cases(3360.0, mujoco=False)] == [
        ("kinematic", 0.0),
        ("kinematic", 3360.0),
    ]
    assert [c.world for c in cases(60.0, mujoco=True)] == ["kinematic", "kinematic", "mujoco"]


def test_the_measuring_process_uses_only_the_stable_replay_api() -> None:
    """The same text measures another checkout's code (a before/after comparison)."""
    assert "RecordedSession.load(" in CHILD
    assert "replay(session)" in CHILD
    assert "bench" not in CHILD


@pytest.mark.slow
def test_a_replay_measured_in_a_fresh_process_reports_its_memory() -> None:
    m = measure(RIG_RECORDING)
    assert m.match
    assert m.final_state == "done"
    assert 0 < m.rss_imported <= m.rss_loaded <= m.peak
    assert m.recorded_s > 10
