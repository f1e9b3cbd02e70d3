"""A fault that never fires is a failure, not a pass: every fault of the file is reported fired or not, and
why not (past the end of the run, a state the job never entered, an occurrence not reached, nothing to act
on); ``dishbot replay --check`` exits 1, ``dishbot run --faults`` prints it, the pytest fixture fails the
test unless it says the fault may not fire. ``occurrence`` counts entries into a state, not resumes."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from cli.main import main
from daemon.app import ServeContext
from replay.harness import DishbotReplay
from tests.daemon.conftest import free_port
from tests.replay.faulty import run_with_faults
from tests.replay.test_run_faults_cli import without_logs

NEVER = (
    '[[fault]]\nkind = "fsr_spike"\nat_s = 5000\n\n'
    '[[fault]]\nkind = "servo_silent"\nservo = 2\nat_state = "recover_lost_mug"\n\n'
    '[[fault]]\nkind = "fsr_spike"\nat_state = "flip"\noccurrence = 9\n\n'
    '[[fault]]\nkind = "fsr_spike"\nat_state = "detect"\nafter_s = 5000\n\n'
    '[[fault]]\nkind = "mug_slip"\nat_state = "detect"\n\n'
    '[[fault]]\nkind = "fsr_spike"\nat_state = "detect"\n'
)


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
def test_every_fault_that_did_not_fire_is_reported_with_why(tmp_path: Path, world: str) -> None:
    run = run_with_faults(tmp_path, NEVER, world=world, mugs=1)
    assert run.result.end_state == "done"
    outcomes = run.injector.outcomes()
    assert [(o.index, o.fired) for o in outcomes] == [
        (1, False),
        (2, False),
        (3, False),
        (4, False),
        (5, False),
        (6, True),
    ]
    end = outcomes[0].reason
    assert end is not None
    assert end.startswith("past the end of the run: due at 5000 s, the run ended at ")
    assert outcomes[1].reason == "the job never entered recover_lost_mug"
    assert outcomes[2].reason == "occurrence 9 not reached: the job entered flip once"
    late = outcomes[3].reason
    assert late is not None
    assert late.startswith("past the end of the run: due at ")
    assert "(at detect + 5000 s)" in late
    held = outcomes[4].reason
    assert held is not None
    assert held.endswith("with nothing to act on: no mug was held")
    assert outcomes[5].reason is None
    assert outcomes[1].line() == (
        "fault 2 (servo_silent at recover_lost_mug): NOT FIRED: the job never entered recover_lost_mug"
    )
    assert [o.index for o in run.injector.unfired()] == [1, 2, 3, 4, 5]


@pytest.mark.slow
def test_occurrence_counts_entries_into_the_state_not_a_resume_after_a_pause(tmp_path: Path) -> None:
    """Paused in the first mug's turn and resumed: the turn is entered again, but not from outside; the
    fault at flip.turn #2 waits for the second mug's turn."""

    def pause_in_the_first_turn(ctx: ServeContext) -> None:
        async def operator() -> None:
            while ctx.job.chart.state != "flip.turn":
                await ctx.clock.sleep(0.01)
            assert (await ctx.handle("pause", b"", False))["ok"]
            await ctx.clock.sleep(1.0)
            assert (await ctx.handle("resume", b"", False))["ok"]

        asyncio.get_running_loop().create_task(operator())

    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "fsr_spike"\nat_state = "flip.turn"\noccurrence = 2\n',
        mugs=2,
        on_ready=pause_in_the_first_turn,
    )
    turns = [e for e in run.events("transition") if e["dest"] == "flip.turn"]
    assert [e["trigger"] != "resume" for e in turns].count(True) >= 2
    assert any(e["trigger"] == "resume" for e in turns)
    second = [e for e in turns if e["trigger"] != "resume"][1]
    injected = run.event("fault_injected")
    assert injected["t"] == second["t"]  # fired as the second mug's turn began, not at the resume
    assert [o.fired for o in run.injector.outcomes()] == [True]


@pytest.mark.slow
def test_replay_check_exits_1_when_a_fault_did_not_fire_and_json_lists_every_fault(
    one_mug_job: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The fault that fires does so as the arm leaves the tray (the job goes on in the simulated cell from
    # there: the rest of the job is all it re-simulates); the one that does not asks for a third look at the
    # counter of a one-mug job, which looks twice.
    faults = tmp_path / "faults.toml"
    faults.write_text(
        '[[fault]]\nkind = "fsr_spike"\nat_state = "place.retreat"\n\n'
        '[[fault]]\nkind = "fsr_spike"\nat_state = "detect"\noccurrence = 3\n'
    )
    capsys.readouterr()
    code = main(["replay", str(one_mug_job), "--faults", str(faults), "--check", "--json"])
    out = without_logs(capsys.readouterr().out)
    assert code == 1
    report = json.loads(out)
    assert report["unfired"] == 1
    assert [(f["index"], f["fired"]) for f in report["fault_outcomes"]] == [(1, True), (2, False)]
    assert report["fault_outcomes"][1]["reason"] == "occurrence 3 not reached: the job entered detect 2 times"
    code = main(["replay", str(one_mug_job), "--faults", str(faults)])
    lines = without_logs(capsys.readouterr().out).splitlines()
    assert code == 0  # without --check: the replay ran
    unfired = "fault 2 (fsr_spike at detect #3): NOT FIRED: occurrence 3 not reached: the job entered detect"
    assert f"{unfired} 2 times" in lines


@pytest.mark.slow
def test_the_fixture_fails_a_test_whose_fault_did_not_fire_unless_it_says_it_may_not(
    one_mug_job: Path, tmp_path: Path
) -> None:
    dishbot = DishbotReplay(tmp_path, {})
    faults = [{"kind": "fsr_spike", "at_s": 9000.0}]
    with pytest.raises(pytest.fail.Exception) as failed:
        dishbot.replay(one_mug_job, faults=faults)
    assert str(failed.value).startswith(
        "fault 1 (fsr_spike at 9000 s): NOT FIRED: past the end of the run: due at 9000 s, the run ended at "
    )
    trace = dishbot.replay(one_mug_job, faults=faults, may_not_fire=[1])
    assert [(o.index, o.fired) for o in trace.unfired] == [(1, False)]
    assert trace.final_state == "done"


@pytest.mark.slow
def test_run_once_prints_the_faults_that_did_not_fire(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "robot.toml"
    config.write_text('robot_id = "cli"\n[planner]\nmethod = "bh"\n')
    faults = tmp_path / "faults.toml"
    faults.write_text(
        '[[fault]]\nkind = "servo_overload"\nservo = 3\nat_state = "flip.turn"\n\n'
        '[[fault]]\nkind = "fsr_spike"\nat_state = "recover_lost_mug"\n'
    )
    capsys.readouterr()
    code = main(
        ["run", "--sim", "--world", "kinematic", "--once", "--config", str(config), "--faults", str(faults),
         "--record-dir", str(tmp_path / "rec"), "--listen", f"tcp/127.0.0.1:{free_port()}"]
    )  # fmt: skip
    out, err = capsys.readouterr()
    lines = without_logs(out).splitlines()
    # stderr holds the progress lines (mug k of N, done) and nothing else: no error, no traceback
    assert all(line.startswith("dishbot run: ") for line in without_logs(err).splitlines()), err
    assert "dishbot run: done (fault" in err
    assert code == 1  # the overload ended the job in fault before it could lose a mug
    assert (
        "fault 2 (fsr_spike at recover_lost_mug): NOT FIRED: the job never entered recover_lost_mug" in lines
    )
    assert lines[-1].startswith("recording ")
