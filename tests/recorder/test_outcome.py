"""What a job's events say happened, named mug by mug with the reason: the fold, the ``--once`` summary, and a
job run through the daemon; and a refused start leaves no recording behind."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from cli.commands.run import _print_summary
from daemon.app import RunResult
from daemon.config import load_config
from daemon.errors import UsageError
from daemon.job import JobSummary, StartRequest
from recorder import read_messages
from recorder.outcome import JobOutcome
from tests.fakes.daemon import serve_daemon
from tests.fakes.job import make_backend, make_world

REFUSAL = "slot for m10: no small mug can be moved there (m10: the gripper would hit mug m9)"


def events() -> list[dict[str, object]]:
    return [
        {"kind": "transition", "trigger": "start", "source": "idle", "dest": "detect"},
        {"kind": "mug_placed", "mug_id": "m2"},
        {"kind": "motion_refused", "mug_id": "m10", "reason": REFUSAL},
        {"kind": "mug_dropped", "mug_id": "m3", "state": "flip.turn"},
        {"kind": "mug_given_up", "mug_id": "m10", "reason": "no motion reaches it"},
        {"kind": "mug_given_up", "mug_id": "m3", "reason": "not seen on the counter"},
        {"kind": "fsr_stale", "device": "fsr", "port": "/dev/fsr"},
        {"kind": "fault", "reason": "BusLost: bus on /dev/servos is gone"},
        {"kind": "transition", "trigger": "fault", "source": "place.transit", "dest": "fault"},
    ]


def test_each_mug_given_up_carries_its_reason_and_what_went_wrong_last() -> None:
    outcome = JobOutcome.of(events())
    assert outcome.failed_lines() == [
        f"m10: no motion reaches it (last refusal: {REFUSAL})",
        "m3: not seen on the counter (last attempt: dropped in flip.turn)",
    ]
    assert outcome.placed == ["m2"]
    assert outcome.drops == {"m3": 1}
    assert outcome.faults == ["BusLost: bus on /dev/servos is gone"]
    assert outcome.device_faults == ["fsr_stale fsr"]
    assert outcome.end_state == "fault"


def test_a_new_start_begins_a_new_outcome() -> None:
    outcome = JobOutcome.of([*events(), {"kind": "transition", "trigger": "start", "dest": "detect"}])
    assert outcome.to_json() == {
        "end_state": None,
        "placed": [],
        "given_up": [],
        "grasp_failures": {},
        "drops": {},
        "faults": [],
        "device_faults": [],
    }


def test_the_once_summary_names_each_failed_mug_with_its_reason(capsys: pytest.CaptureFixture[str]) -> None:
    summary = JobSummary(detected=12, planned=10, placed=9, failed=1)
    result = RunResult(summary, Path("r/x-job.mcap"), "fault", JobOutcome.of(events()))
    _print_summary(result)
    assert capsys.readouterr().out.splitlines() == [
        "job ended in state fault",
        "detected 12, planned 10, placed 9, failed 1",
        "grasp failures 0, drops 0, duration 0.0 s",
        f"failed m10: no motion reaches it (last refusal: {REFUSAL})",
        "failed m3: not seen on the counter (last attempt: dropped in flip.turn)",
        "fault: BusLost: bus on /dev/servos is gone",
        "recording r/x-job.mcap",
    ]


@pytest.mark.slow
def test_a_job_through_the_daemon_records_and_reports_the_mug_it_gave_up(tmp_path: Path) -> None:
    config = load_config(overrides={"robot_id": "out", "planner": {"method": "bh"}})

    async def run() -> RunResult:
        # A mug the plan can reach but no grasp holds (one out of reach is left out of the plan instead).
        world = make_world(3)
        world.always_fail = {"true1"}
        return await serve_daemon(config, make_backend(world), tmp_path, once=StartRequest())

    result = asyncio.run(run())
    assert result.end_state == "done"
    (line,) = result.outcome.failed_lines()
    assert line.startswith("m")
    assert ": given up after 3 attempts (last attempt: grasp failed in " in line
    assert sorted(result.outcome.placed) == sorted(set(result.outcome.placed))
    assert len(result.outcome.placed) == 2
    recorded = [m.payload for m in read_messages(result.recording) if m.topic.endswith("/events")]
    assert JobOutcome.of(recorded).failed_lines() == [line]  # record info says the same


@pytest.mark.slow
def test_a_start_refused_for_a_zenoh_endpoint_in_use_leaves_no_file(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        listen = (f"tcp/127.0.0.1:{port}",)

        async def run() -> None:
            await serve_daemon(load_config(), make_backend(make_world(1)), tmp_path / "rec", listen=listen)

        with pytest.raises(UsageError, match=r"^cannot open the Zenoh session \(listen \['tcp/127\.0\.0\.1:"):
            asyncio.run(run())
    assert list((tmp_path / "rec").iterdir()) == []


@pytest.mark.slow
def test_a_start_refused_for_a_foxglove_port_in_use_leaves_no_file(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        foxglove = ("127.0.0.1", port)

        async def run() -> None:
            await serve_daemon(
                load_config(), make_backend(make_world(1)), tmp_path / "rec", foxglove=foxglove
            )

        with pytest.raises(UsageError, match=rf"^cannot start the Foxglove server on 127\.0\.0\.1:{port}: "):
            asyncio.run(run())
    assert list((tmp_path / "rec").iterdir()) == []
