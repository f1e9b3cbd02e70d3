"""``dishbot run --sim --faults FILE``: a bad file is refused in one line before anything starts (exit 2);
a good one is injected into the live daemon and the ``--once`` summary says what fired."""

from __future__ import annotations

from pathlib import Path

import pytest

from cli.main import main
from recorder import read_messages
from tests.daemon.conftest import free_port


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, without_logs(out), without_logs(err)


def without_logs(text: str) -> str:
    return "".join(line for line in text.splitlines(keepends=True) if not line.startswith("20"))


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text('robot_id = "cli"\n[planner]\nmethod = "bh"\n')
    return path


def test_a_bad_fault_file_exits_2_with_one_line_naming_the_entry(
    tmp_path: Path, config: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    faults = tmp_path / "faults.toml"
    faults.write_text(
        '[[fault]]\nkind = "fsr_drop"\nat_s = 1\n\n[[fault]]\nkind = "servo_overload"\nat_s = 2\n'
    )
    code, out, err = run(
        capsys, "run", "--sim", "--once", "--config", str(config), "--faults", str(faults),
        "--record-dir", str(tmp_path / "rec"),
    )  # fmt: skip
    assert code == 2
    assert err == (
        f"dishbot run: error: {faults}: fault 2 (servo_overload): servo: missing (the servo ID the fault "
        "acts on)\n"
    )
    assert out == ""
    assert not (tmp_path / "rec").exists()  # refused before the daemon started


def test_a_missing_fault_file_and_a_servo_outside_the_chain_exit_2(
    tmp_path: Path, config: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run(capsys, "run", "--sim", "--config", str(config), "--faults", str(tmp_path / "no.toml"))
    assert (code, err) == (2, f"dishbot run: error: {tmp_path / 'no.toml'}: no such fault file\n")
    faults = tmp_path / "faults.toml"
    faults.write_text('[[fault]]\nkind = "servo_silent"\nservo = 7\nat_s = 1\n')
    code, _, err = run(capsys, "run", "--sim", "--config", str(config), "--faults", str(faults))
    assert code == 2
    assert err.endswith(
        "fault 1 (servo_silent): servo: no servo 7 in the configured chain (1, 2, 3, 4, 5, 6)\n"
    )


def test_faults_without_the_simulated_cell_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "robot.toml"
    config.write_text('robot_id = "cli"\nbackend = "hardware"\n')
    faults = tmp_path / "faults.toml"
    faults.write_text('[[fault]]\nkind = "fsr_drop"\nat_s = 1\n')
    code, _, err = run(capsys, "run", "--config", str(config), "--faults", str(faults))
    assert (code, err) == (
        2,
        "dishbot run: error: --faults injects faults into the simulated cell; add --sim (backend is "
        "hardware)\n",
    )


@pytest.mark.slow
def test_a_once_job_with_a_fault_file_prints_the_faults_fired_and_records_them(
    tmp_path: Path, config: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    faults = tmp_path / "faults.toml"
    faults.write_text('[[fault]]\nkind = "servo_overload"\nservo = 3\nat_state = "flip.turn"\n')
    code, out, _ = run(
        capsys, "run", "--sim", "--world", "kinematic", "--once", "--config", str(config),
        "--faults", str(faults), "--record-dir", str(tmp_path / "rec"),
        "--listen", f"tcp/127.0.0.1:{free_port()}",
    )  # fmt: skip
    assert code == 1  # the job ended in fault
    lines = out.splitlines()
    assert lines[0] == "job ended in state fault"
    assert (
        "fault: ServoFault: servo 3 on inprocess:ttyDXL reports overload; its torque is off until the "
        "fault is cleared" in lines
    )
    fired = [line for line in lines if line.startswith("fault fired: ")]
    assert len(fired) == 1
    assert fired[0].startswith("fault fired: servo_overload servo 3 at ")
    recording = Path(lines[-1].removeprefix("recording "))
    messages = list(read_messages(recording))
    injected = [
        m.payload for m in messages if m.topic.endswith("/events") and m.payload["kind"] == "fault_injected"
    ]
    assert [(e["fault"], e["servo"], e["state"]) for e in injected] == [("servo_overload", 3, "flip.turn")]
    logged = [
        m.payload for m in messages if m.topic.endswith("/log") and m.payload.get("event") == "fault_injected"
    ]
    assert len(logged) == 1
    assert fired[0] == f"fault fired: servo_overload servo 3 at {injected[0]['fired_at_s']:.1f} s"
