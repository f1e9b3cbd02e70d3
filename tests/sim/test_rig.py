"""``dishbot sim rig``: the simulated cell as separate devices, driven by ``dishbot run`` through the hardware
backend exactly as the robot is (the real dynamixel-sdk and FSR reader on the rig's pseudo-terminals, the
depth camera's frames over real Zenoh on loopback), in the MuJoCo world and in the kinematic one."""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from cli.main import main
from daemon.config import load_config
from recorder import read_messages
from sim.counter import dataset_counter
from tests.daemon.conftest import free_port
from validation.toml import dumps

# The tests whose devices answer on pseudo-terminals in real time run one at a time (pytest-xdist group).
# tests/bench/test_bus.py, tests/drivers/test_cli.py and tests/drivers/test_docs_example.py name it too.
REALTIME_PTY = "realtime-pty"
# Guards against a hang, not measurements: the rig runs in real time and a one-mug job takes about 30 s.
READY_GUARD_S = 120.0
JOB_GUARD_S = 300.0
RIG = [sys.executable, "-m", "cli.main", "sim", "rig"]
RUN = [sys.executable, "-m", "cli.main", "run", "--once"]


def first_mug(tmp_path: Path) -> Path:
    config = load_config()
    mug = dataset_counter(1, config.cell, config.mug_catalogue()).mugs[0]
    path = tmp_path / "mugs.json"
    path.write_text(json.dumps([{"id": "m1", "type": mug.spec.name, "x_m": mug.x_m, "y_m": mug.y_m}]))
    return path


def patient(config_path: Path) -> Path:
    """The rig's config with the waits of a loaded machine: the rig's devices answer on pseudo-terminals in
    real time, and a test machine that shares its cores (a parallel suite, CI) can keep the rig process
    from answering within the robot's 20 ms status wait or its FSR's 0.2 s stale limit. This test drives the
    hardware path end to end; the status timeout and the stale limit have tests of their own."""
    document = tomllib.loads(config_path.read_text())
    document["hardware"] |= {"read_timeout_s": 0.25, "retries": 4}
    document["hardware"]["fsr"] = {**document["hardware"].get("fsr", {}), "stale_after_s": 2.0}
    patient = config_path.with_name("robot-patient.toml")
    patient.write_text(dumps(document))
    return patient


def ready_line(process: subprocess.Popen[str]) -> str:
    assert process.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(process.stdout, selectors.EVENT_READ)
        if not sel.select(READY_GUARD_S):
            raise AssertionError("the rig did not say it was ready")
    return process.stdout.readline()


@pytest.mark.slow
@pytest.mark.xdist_group(REALTIME_PTY)
@pytest.mark.parametrize("world", ["mujoco", "kinematic"])
def test_dishbot_run_drives_the_rig_through_the_hardware_backend(tmp_path: Path, world: str) -> None:
    rig_endpoint = f"tcp/127.0.0.1:{free_port()}"
    config_path = tmp_path / "rig" / "robot.toml"
    config_path.parent.mkdir()
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    rig = subprocess.Popen(
        [
            *RIG,
            "--world",
            world,
            "--mugs",
            str(first_mug(tmp_path)),
            "--listen",
            rig_endpoint,
            "--write-config",
            str(config_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    try:
        line = ready_line(rig)
        assert line.startswith("rig ready: 1 mugs; servos ")
        assert (config_path.parent / "dishbot-servos").is_symlink()
        config = load_config(config_path)
        assert config.backend == "hardware"
        assert config.hardware.camera == "zenoh"
        assert config.hardware.zenoh_camera.connect == rig_endpoint
        assert config.hardware.servo_port == str(config_path.parent / "dishbot-servos")
        config_path = patient(config_path)
        record_dir = tmp_path / "recordings"
        daemon_endpoint = f"tcp/127.0.0.1:{free_port()}"
        run = subprocess.run(
            [
                *RUN,
                "--config",
                str(config_path),
                "--record-dir",
                str(record_dir),
                "--listen",
                daemon_endpoint,
            ],
            capture_output=True,
            text=True,
            timeout=JOB_GUARD_S,
            env=env,
        )
        assert run.returncode == 0, run.stderr[-3000:]
        assert "job ended in state done" in run.stdout
        assert "detected 1, planned 1, placed 1, failed 0" in run.stdout
        (recording,) = record_dir.glob("*-job.mcap")
        got = read_messages(recording)
        header = next(m.payload for m in got if m.topic == "session/header")
        assert header["config"]["backend"] == "hardware"  # type: ignore[index]
        assert got.topic_counts["dishbot/dishbot/input/joints"] > 100  # the arm read over the rig's bus
        assert got.topic_counts["dishbot/dishbot/input/observation"] >= 1  # frames that came over Zenoh
        # The robot's recording replays: its inputs served in the kinematic stand-in, the trace matched.
        assert main(["--log-level", "warning", "replay", str(recording), "--check"]) == 0
    finally:
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=60) == 0
    assert not (config_path.parent / "dishbot-servos").exists()  # the links go with the rig


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--world", "gazebo"], "--world gazebo: choose one of mujoco, kinematic"),
        (["--camera-hz", "100"], "--camera-hz 100 is out of range; allowed [0.5, 30]"),
        (["--listen", "127.0.0.1:7460"], "--listen: '127.0.0.1:7460' is not a Zenoh endpoint"),
        (["--camera-key", "cam/*"], "--camera-key: 'cam/*' is not a plain Zenoh key (no wildcards)"),
        (["--dataset", "5"], "sim rig: "),
        (["--dataset", "0"], "--dataset 0: choose a dataset 1-6"),  # before: taken for the default, 1
        (["--dataset", "7"], "--dataset 7: choose a dataset 1-6"),
    ],
)
def test_bad_rig_arguments_are_refused_in_one_line_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    target = tmp_path / "robot.toml"
    code, err = run_cli(["sim", "rig", "--write-config", str(target), *extra], capsys)
    assert code == 2
    assert err.startswith(f"dishbot sim: error: {message}")
    assert len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []  # nothing written, no links


def test_the_rig_never_overwrites_a_config_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "robot.toml"
    target.write_text('robot_id = "mine"\n')
    code, err = run_cli(["sim", "rig", "--write-config", str(target)], capsys)
    assert code == 2
    assert (
        err
        == f"dishbot sim: error: --write-config {target}: exists, not written by a rig; choose a new name\n"
    )
    assert target.read_text() == 'robot_id = "mine"\n'


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("[", "not valid JSON: "),
        (
            '[{"id": "m1", "type": "teacup", "x_m": 0.3, "y_m": 0.4}]',
            "mugs[0].type: 'teacup' is not a configured mug type (big, small)",
        ),
        ("[]", "mugs: expected 1-64 values, got 0"),
    ],
)
def test_a_bad_mugs_file_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str, message: str
) -> None:
    mugs = tmp_path / "mugs.json"
    mugs.write_text(content)
    target = tmp_path / "robot.toml"
    code, err = run_cli(["sim", "rig", "--mugs", str(mugs), "--write-config", str(target)], capsys)
    assert code == 2
    assert err.startswith(f"dishbot sim: error: --mugs {mugs}: {message}")
    assert not target.exists()
