"""``dishbot record info`` summarises finished, live and cut recordings, with the job's outcome, and refuses
bad files in one line."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from cli.main import main
from recorder import Recorder

RecordingFactory = Callable[..., Path]
T0 = 1_790_000_000_000_000_000


def test_info_summarises_a_finished_recording(
    make_recording: RecordingFactory, capsys: pytest.CaptureFixture[str]
) -> None:
    path = make_recording(seconds=2.0)
    capsys.readouterr()
    assert main(["record", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[1:10] == [
        "status:    finished",
        "kind:      -",
        "robot id:  r1",
        "dataset:   1",
        "start:     2026-09-21T14:13:20.000Z",
        "end:       2026-09-21T14:13:21.981Z",
        "duration:  1.981 s",
        "messages:  205",
        "",
    ]
    assert out.splitlines()[10:] == [
        "topic                         schema                     messages",
        "----------------------------  -------------------------  --------",
        "dishbot/r1/input/force        dishbot.input_force             100",
        "dishbot/r1/input/joints       dishbot.input_joints            100",
        "dishbot/r1/input/observation  dishbot.input_observation         4",
        "session/header                dishbot.session_header            1",
    ]


def job_file(path: Path, *, finish: bool = True) -> Recorder:
    """A job file as the daemon writes it: header with the job, events of one job with a given-up mug."""
    rec = Recorder(path, chunk_size=1024)
    rec.write_header(
        {"robot_id": "r1"},
        {"dataset": None},
        log_time_ns=T0,
        job={
            "dataset": None,
            "mugs": [{"id": "a", "type": "big", "x_m": 0.1, "y_m": 0.4}, {"id": "b"}],
            "planner": {"method": "bh", "cost": "upc", "fitness": "rf", "time_limit_s": 1.0, "seed": 7},
            "sim_seed": 3,
        },
        file={"kind": "job", "index": 2, "pid": 4242, "previous": "r1-x-idle.mcap"},
    )
    events: list[dict[str, Any]] = [
        {"kind": "transition", "trigger": "start", "source": "idle", "dest": "detect"},
        {"kind": "mug_placed", "mug_id": "a", "x_m": 0.5, "y_m": 0.0},
        {"kind": "grasp_failed", "mug_id": "b", "state": "side_grasp.verify"},
        {"kind": "mug_given_up", "mug_id": "b", "reason": "given up after 3 attempts"},
        {"kind": "servo_fault", "device": "servo 3", "error": "overload"},
        {"kind": "transition", "trigger": "next", "source": "detect", "dest": "done"},
    ]
    for i, event in enumerate(events):
        rec.write(
            "dishbot/r1/events", {"state": "detect", "t": 0.0, **event}, log_time_ns=T0 + (i + 1) * 10**9
        )
    if finish:
        rec.close()
    return rec


def test_info_names_what_the_job_ran_and_how_it_went(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "r1-job.mcap"
    job_file(path)
    capsys.readouterr()
    assert main(["record", "info", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1:8] == [
        "status:    finished",
        "kind:      job",
        "robot id:  r1",
        "mugs:      2 given: a b",
        "planner:   bh, cost upc, fitness rf, time limit 1.0 s, seed 7",
        "sim seed:  3",
        "start:     2026-09-21T14:13:20.000Z",
    ]
    outcome = lines[lines.index("outcome:   done") :]
    assert outcome[:9] == [
        "outcome:   done",
        "placed:    1: a",
        "given up:  1",
        "  b: given up after 3 attempts (last attempt: grasp failed in side_grasp.verify)",
        "grasp failures: b ×1",
        "faults:    0",
        "device faults: 1",
        "  servo_fault servo 3 overload",
        "",
    ]


def test_info_tells_a_file_being_written_from_one_cut_by_a_crash(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "r1-live.mcap"
    rec = job_file(path, finish=False)
    try:
        rec.write("dishbot/r1/state", {"state": "detect"}, log_time_ns=T0 + 10**10)
        capsys.readouterr()
        for _ in range(500):  # until the recorder's thread has written the events (it flushes every 0.5 s)
            assert main(["record", "info", str(path), "--json"]) == 0
            doc = json.loads(capsys.readouterr().out)
            if doc["messages"] >= 8:
                break
            time.sleep(0.01)
        assert doc["messages"] == 8
        assert doc["being_written"] is True
        assert doc["truncated"] is True
        assert doc["finished"] is False
        assert (
            doc["status"]
            == f"being written by a running recorder (pid 4242); {doc['messages']} messages so far"
        )
        assert doc["outcome"]["end_state"] == "done"
    finally:
        rec.close()
    cut = tmp_path / "r1-cut.mcap"
    cut.write_bytes(path.read_bytes()[:-200])  # a copy cut short: nobody writes it
    assert main(["record", "info", str(cut), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["being_written"] is False
    assert doc["status"].startswith("cut by a crash or a partial copy at byte ")


def test_info_json_reports_a_cut_file_and_what_was_recovered(
    make_recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = make_recording(seconds=4.0).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    assert main(["record", "info", str(cut), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["truncated"] is True
    assert doc["being_written"] is False
    assert doc["cut_at_byte"] <= len(data) // 2
    assert 0 < doc["messages"] < 405
    assert doc["robot_id"] == "r1"
    assert doc["status"] == (
        f"cut by a crash or a partial copy at byte {doc['cut_at_byte']} (after {doc['cut_after_s']:.3f} s); "
        f"{doc['messages']} messages recovered (file ends mid-record)"
    )
    assert doc["cut_after_s"] == doc["duration_s"]
    assert sum(doc["topics"].values()) == doc["messages"]


def test_info_text_says_where_a_cut_file_ends(
    make_recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = make_recording(seconds=4.0).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:6000])
    capsys.readouterr()
    assert main(["record", "info", str(cut)]) == 0
    status = capsys.readouterr().out.splitlines()[1]
    assert status.startswith("status:    cut by a crash or a partial copy at byte ")
    assert status.endswith(" messages recovered (file ends mid-record)")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "dishbot record: error: {path}: no such file"),
        (b"", "dishbot record: error: {path}: empty file, not a recording"),
        (b"PK\x03\x04 a zip file", "dishbot record: error: {path}: not an MCAP file (bad magic)"),
        (
            b"\x89MC",
            "dishbot record: error: {path}: cut inside the MCAP magic after 3 bytes, nothing recorded",
        ),
    ],
)
def test_info_refuses_bad_files_with_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes | None, message: str
) -> None:
    path = tmp_path / "x.mcap"
    if content is not None:
        path.write_bytes(content)
    assert main(["record", "info", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == message.format(path=path) + "\n"
