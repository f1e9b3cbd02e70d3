"""The hardware backend: the shared device stack on the configured ports (here the pty simulators: the
robot's code path), the RealSense observer (a camera stand-in here), and every way a start is refused."""

from __future__ import annotations

import asyncio
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cli.main import main
from daemon.backend import SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.errors import ConfigError, UsageError
from daemon.hardware import open_hardware_backend
from daemon.planners import check_cell_reachable, load_correction
from description.camera import CameraSpec
from description.thesis import JOINT_SERVOS
from drivers.interfaces import RGBDFrame
from drivers.sim import default_chain
from drivers.stack import ARM_JOINTS
from planning.arm import ArmModel
from planning.arm.calibration import PositionCorrection
from tests.fakes.hw_rig import rig


class TableCamera:
    """A camera stand-in: the configured pinhole looking at an empty table (depth of the z = 0 plane)."""

    def __init__(self, spec: CameraSpec) -> None:
        self.K = spec.intrinsics()
        self.T = spec.world_from_camera()
        self.captures = 0

    async def capture(self) -> RGBDFrame:
        self.captures += 1
        K = self.K
        u, v = np.meshgrid(np.arange(K.width) + 0.5, np.arange(K.height) + 0.5)
        rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1)
        R, origin = self.T[:3, :3], self.T[:3, 3]
        dz = rays @ R[2]  # world z change per metre of camera depth
        depth = np.where(dz < -1e-6, -origin[2] / np.where(dz < -1e-6, dz, -1.0), 0.0)
        return RGBDFrame(time.monotonic(), depth.astype(np.float32), K, self.T, meta={"source": "table"})


def test_the_default_servos_are_the_thesis_chain_ids_1_to_6() -> None:
    servos = load_config().hardware.servos
    assert [(s.joint, s.id, s.model) for s in servos] == [
        (name, i, model) for i, (name, model) in enumerate(JOINT_SERVOS, start=1)
    ]


def test_the_hardware_backend_runs_the_shared_device_stack_on_the_configured_ports() -> None:
    async def go() -> None:
        with rig(hardware={"camera": "realsense"}) as r:
            camera = TableCamera(r.config.cell.camera)
            backend = await open_hardware_backend(r.config, camera=camera)
            try:
                assert backend.name == "hardware"
                assert backend.devices is not None
                assert backend.devices.chain.expected == default_chain()
                assert backend.devices.chain.config.port == r.servos.device_path
                js = await backend.arm.read_joints()
                assert js.names == ARM_JOINTS
                assert np.allclose(js.position_rad, 0.0, atol=0.01)
                gripper = await backend.gripper.read()
                assert 0.08 < gripper.aperture_m < 0.1  # the simulated gripper servo starts at 0 rad
                await asyncio.sleep(0.1)
                reading = backend.force.latest()
                assert reading is not None
                assert reading.force_n == 0.0
                obs = await backend.observer.observe()
                assert camera.captures == 1
                assert obs.detections == ()  # an empty table
                assert obs.depth_preview is not None
            finally:
                await backend.close()
            # closing turned every servo's torque off
            assert all(r.servos.servo(i).get("torque_enable") == 0 for i, _ in default_chain())

    asyncio.run(go())


def test_a_port_that_does_not_exist_is_refused_in_one_line() -> None:
    with rig(hardware={"servo_port": "/dev/dishbot-nothing-here"}) as r, pytest.raises(UsageError) as info:
        asyncio.run(open_hardware_backend(r.config))
    assert str(info.value) == (
        "hardware.servo_port: /dev/dishbot-nothing-here does not exist; plug the adapter in and install the "
        "udev rule (docs/hardware.md), or set the port"
    )


def test_a_missing_fsr_port_is_refused_in_one_line() -> None:
    with rig(hardware={"fsr": {"port": "/dev/dishbot-no-fsr"}}) as r, pytest.raises(UsageError) as info:
        asyncio.run(open_hardware_backend(r.config))
    assert str(info.value).startswith("hardware.fsr.port: /dev/dishbot-no-fsr does not exist; ")


def test_a_missing_pyrealsense2_is_refused_before_any_device_opens(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import fails as when it is not installed
    with rig(hardware={"camera": "realsense"}) as r:
        with pytest.raises(UsageError) as info:
            asyncio.run(open_hardware_backend(r.config))
        assert r.servos.packets_seen == 0
    assert str(info.value) == (
        "hardware.camera: pyrealsense2 is not installed; install the optional extra with "
        "`pip install 'dishbot[realsense]'`"
    )


def test_a_chain_that_does_not_match_the_config_is_refused_with_the_torque_off() -> None:
    with rig(hardware={"servos": {"shoulder_lift": {"id": 2, "model": "MX-64T"}}}) as r:
        with pytest.raises(UsageError) as info:
            asyncio.run(open_hardware_backend(r.config))
        assert all(r.servos.servo(i).get("torque_enable") == 0 for i, _ in default_chain())
    message = str(info.value)
    assert message.startswith("cannot open the robot's devices: ")
    assert "servo 2" in message
    assert "MX-106T" in message
    assert "\n" not in message


def test_run_without_sim_on_a_missing_port_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "robot.toml"
    path.write_text('backend = "hardware"\n[hardware]\nservo_port = "/dev/dishbot-gone"\n')
    assert main(["run", "--config", str(path), "--record-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        "dishbot run: error: hardware.servo_port: /dev/dishbot-gone does not exist; plug the adapter in and "
        "install the udev rule (docs/hardware.md), or set the port"
    )


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--world", "mujoco"], "--world sets up the simulated cell; add --sim (backend is hardware)"),
        (["--dataset", "2"], "--dataset sets up the simulated cell; add --sim (backend is hardware)"),
        (["--speed", "2"], "--speed sets up the simulated cell; add --sim (backend is hardware)"),
        (["--transport", "pty"], "--transport sets up the simulated cell; add --sim (backend is hardware)"),
    ],
)
def test_simulation_flags_on_the_hardware_backend_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], message: str
) -> None:
    path = tmp_path / "robot.toml"
    path.write_text('backend = "hardware"\n')
    assert main(["run", "--config", str(path), "--record-dir", str(tmp_path), *flags]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"dishbot run: error: {message}"


def test_a_cell_the_arm_cannot_serve_is_refused_naming_the_corners(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    far = load_config(overrides={"cell": {"tray_origin_m": [0.9, -0.187]}})
    with pytest.raises(UsageError) as info:
        check_cell_reachable(far, ArmModel.load())
    message = str(info.value)
    assert message.startswith("the arm cannot serve the configured cell: tray point (0.9")
    assert "\n" not in message
    check_cell_reachable(load_config(), ArmModel.load())  # the default cell is fine
    path = tmp_path / "far.toml"
    path.write_text("[cell]\ntray_origin_m = [0.9, -0.187]\n")
    assert main(["run", "--sim", "--once", "--config", str(path), "--record-dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"dishbot run: error: {message}"
    assert not list(tmp_path.glob("*.mcap"))  # refused before anything started


def test_the_arm_calibration_file_reaches_the_cycle_planner(tmp_path: Path) -> None:
    correction = PositionCorrection(((0.001,) + (0.0,) * 6, (0.0,) * 7, (-0.002,) + (0.0,) * 6))
    path = tmp_path / "arm.json"
    path.write_text(__import__("json").dumps(correction.to_mapping()))
    config = load_config(overrides={"arm": {"calibration_file": str(path)}})
    assert load_correction(config) == correction
    clock = SimulatedClock()
    backend = clock.run(open_backend(config, sim=SimOptions(world="kinematic"), clock=clock))
    assert getattr(backend.motion, "correction") == correction  # noqa: B009
    bad = load_config(overrides={"arm": {"calibration_file": str(tmp_path / "missing.json")}})
    with pytest.raises(UsageError) as info:
        load_correction(bad)
    assert str(info.value) == (
        f"arm.calibration_file: cannot read the calibration file {tmp_path / 'missing.json'}: "
        "No such file or directory"
    )


BAD_HARDWARE: list[tuple[dict[str, Any], str]] = [
    ({"protocol": 3}, "hardware.protocol: 3 is out of range; allowed [1, 2]"),
    (
        {"baudrate": 250000},
        "hardware.baudrate: 250000 is not a Protocol 1.0 rate; use 9600, 19200, 57600, 115200, 500000, "
        "1000000",
    ),
    (
        {"servos": {"elbow_lift": {"id": 2, "model": "MX-64T"}}},
        "hardware.servos.elbow_lift.id: 2 is already the id of shoulder_lift; every servo on the bus "
        "needs its own id",
    ),
    (
        {"servos": {"gripper": {"id": 6, "model": "XL430-W250"}}},
        "hardware.servos.gripper.model: XL430-W250 speaks Protocol 2.0 but hardware.protocol is 1",
    ),
    (
        {"servos": {"gripper": {"id": 6, "model": "AX-18"}}},
        "hardware.servos.gripper.model: 'AX-18' is not one of AX-12A, MX-28T, MX-64T, MX-106T, XL430-W250, "
        "XM430-W350, XL330-M288",
    ),
    (
        {"servos": {"elbow": {"id": 9, "model": "AX-12A"}}},
        "hardware.servos.elbow: unknown key in hardware.servos",
    ),
    (
        {"servos": {"gripper": {"id": 300, "model": "AX-12A"}}},
        "hardware.servos.gripper.id: 300 is out of range",
    ),
    (
        {"fsr": {"release_n": 2.0}},
        "hardware.fsr.release_n: 2 must be below threshold_n 1 (the hysteresis of the grasp detection)",
    ),
    ({"fsr": {"port": ""}}, "hardware.fsr.port: expected a non-empty string, got ''"),
    (
        {"gripper": {"aperture_map": [[0.5, 0.1], [0.1, 0.05]]}},
        "hardware.gripper.aperture_map: needs at least two [angle, aperture] points in strictly "
        "increasing angle",
    ),
    (
        {"gripper": {"aperture_map": [[0.5]]}},
        "hardware.gripper.aperture_map[0]: expected 2 values, got 1",
    ),
    ({"camera": "kinect"}, "hardware.camera: 'kinect' is not one of realsense, zenoh, none"),
    ({"read_timeout_s": 0}, "hardware.read_timeout_s: 0 is out of range; allowed [0.001, 1]"),
]


@pytest.mark.parametrize(
    ("override", "message"), BAD_HARDWARE, ids=[m.split(":")[0] for _, m in BAD_HARDWARE]
)
def test_a_bad_hardware_value_is_refused_naming_the_field(override: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(overrides={"hardware": override})
    assert str(info.value).startswith(message)
