"""``dishbot run --sim --once --mugs FILE``: the once job's counter is the file's mugs, and its recording
replays to a match; a bad file or flag is one line on stderr and exit 2, before anything starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main
from recorder import read_messages
from tests.daemon.conftest import free_port
from tests.fakes.counter import dataset_mugs, mugs_file


@pytest.mark.slow
def test_a_once_job_on_one_listed_mug_places_it_and_its_recording_replays(tmp_path: Path) -> None:
    record_dir = tmp_path / "recordings"
    cmd = [sys.executable, "-B", "-m", "cli.main", "run", "--sim", "--world", "kinematic", "--once"]
    cmd += ["--mugs", str(mugs_file(tmp_path, 1)), "--record-dir", str(record_dir)]
    cmd += ["--listen", f"tcp/127.0.0.1:{free_port()}"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "detected 1, planned 1, placed 1, failed 0\n" in done.stdout
    (job,) = record_dir.glob("*-job.mcap")
    header = next(m.payload for m in read_messages(job) if m.topic == "session/header")
    assert header["job"]["mugs"] == dataset_mugs(1)  # type: ignore[index]
    assert main(["--log-level", "warning", "replay", str(job), "--check"]) == 0


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "cannot read it: No such file or directory"),
        ("[", "not valid JSON: Expecting value at line 1 column 2"),
        ('[{"id": "m1", "type": "small", "x_m": 0.3}]', "mugs[0].y_m: missing"),
        (
            '[{"id": "m1", "type": "teacup", "x_m": 0.3, "y_m": 0.4}]',
            "mugs[0].type: 'teacup' is not a configured mug type (big, small)",
        ),
        ("[]", "mugs: expected 1-64 values, got 0"),
    ],
    ids=["missing", "not-json", "missing-field", "unknown-type", "empty"],
)
def test_a_bad_mugs_file_is_one_line_naming_it_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, message: str
) -> None:
    path = tmp_path / "mugs.json"
    if content is not None:
        path.write_text(content)
    record_dir = tmp_path / "recordings"
    argv = ["run", "--sim", "--once", "--mugs", str(path), "--record-dir", str(record_dir)]
    assert main(argv) == 2
    assert capsys.readouterr().err == f"dishbot run: error: --mugs {path}: {message}\n"
    assert not record_dir.exists()  # nothing started


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            ["--sim", "--once", "--dataset", "2"],
            "--dataset and --mugs both set the counter up: give one of them",
        ),
        (
            ["--sim"],
            "--mugs sets up the counter of the --once job; a daemon waiting for start takes the mugs from "
            "`dishbot start --mugs FILE`",
        ),
        (
            ["--once", "--config", "HARDWARE"],
            "--mugs sets up the simulated cell; add --sim (backend is hardware)",
        ),
    ],
    ids=["with-dataset", "without-once", "hardware"],
)
def test_mugs_with_a_flag_that_contradicts_it_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    hardware = tmp_path / "robot.toml"
    hardware.write_text('backend = "hardware"\n')
    extra = [str(hardware) if a == "HARDWARE" else a for a in extra]
    record_dir = tmp_path / "recordings"
    path = mugs_file(tmp_path, 1)
    assert main(["run", *extra, "--mugs", str(path), "--record-dir", str(record_dir)]) == 2
    assert capsys.readouterr().err == f"dishbot run: error: {message}\n"
    assert not record_dir.exists()


@pytest.mark.parametrize("verb", [["start"], ["sim", "rig", "--write-config", "RIG"]])
def test_start_and_sim_rig_refuse_a_file_that_is_not_json_as_run_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], verb: list[str]
) -> None:
    path = tmp_path / "mugs.json"
    path.write_text("[")
    argv = [str(tmp_path / "rig.toml") if a == "RIG" else a for a in verb]
    assert main([*argv, "--mugs", str(path)]) == 2  # start: before any session opens, nothing sent
    message = f"--mugs {path}: not valid JSON: Expecting value at line 1 column 2"
    assert capsys.readouterr().err == f"dishbot {verb[0]}: error: {message}\n"
