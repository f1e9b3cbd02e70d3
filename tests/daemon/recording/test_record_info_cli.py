"""``dishbot record info`` summarises finished and cut recordings and refuses bad files in one line."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from daemon.cli import main

RecordingFactory = Callable[..., Path]


def test_info_summarises_a_finished_recording(
    make_recording: RecordingFactory, capsys: pytest.CaptureFixture[str]
) -> None:
    path = make_recording(seconds=2.0)
    capsys.readouterr()
    assert main(["record", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[1:9] == [
        "status:    finished",
        "robot id:  r1",
        "dataset:   1",
        "start:     2026-09-21T14:13:20.000Z",
        "end:       2026-09-21T14:13:21.981Z",
        "duration:  1.981 s",
        "messages:  205",
        "",
    ]
    assert out.splitlines()[9:] == [
        "topic                         messages",
        "----------------------------  --------",
        "dishbot/r1/input/force             100",
        "dishbot/r1/input/joints            100",
        "dishbot/r1/input/observation         4",
        "session/header                       1",
    ]


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
    assert doc["cut_at_byte"] <= len(data) // 2
    assert 0 < doc["messages"] < 405
    assert doc["robot_id"] == "r1"
    assert doc["status"] == (
        f"truncated at byte {doc['cut_at_byte']} (after {doc['cut_after_s']:.3f} s); "
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
    assert status.startswith("status:    truncated at byte ")
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
