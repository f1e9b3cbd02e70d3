"""Config loading: defaults are valid, overrides merge, each class of bad value names field and range."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

import pytest

from cli.main import main
from daemon.config import load_cell_and_planner, load_config, parse_config, to_toml
from daemon.errors import ConfigError
from description import thesis
from description.camera import CameraSpec
from description.cell import CellLayout, Tray
from drivers.dynamixel.config import HealthLimits
from drivers.fsr import FsrSettings
from perception.frames import FrameLimits
from validation import Invalid


def test_the_embedded_defaults_load() -> None:
    config = load_config()
    assert config.robot_id == "dishbot"
    assert config.zenoh.listen == ("tcp/127.0.0.1:3474",)
    assert [m.name for m in config.mug_types] == ["big", "small"]
    assert config.mug_type("big").diameter_mm == 91


def test_the_cell_and_planner_alone_are_those_of_the_whole_config(tmp_path: Path) -> None:
    """``dishbot plan`` reads only the embedded defaults' cell and planner tables; a file is still loaded and
    checked whole, so a bad value anywhere in it fails as ``load_config`` fails."""
    config = load_config()
    assert load_cell_and_planner() == (config.cell, config.planner)
    path = tmp_path / "robot.toml"
    path.write_text('[planner]\nfootprint = "rect"\n[cell]\ntray_size_mm = [300, 350]\n')
    config = load_config(path)
    assert load_cell_and_planner(path) == (config.cell, config.planner)
    assert (config.planner.footprint, config.cell.tray.size_mm) == ("rect", (300, 350))
    path.write_text("[hardware]\nbaudrate = 12\n")
    with pytest.raises(ConfigError, match=r"^hardware\.baudrate: "):
        load_cell_and_planner(path)


def test_a_file_overrides_only_the_keys_it_names(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text('robot_id = "kitchen-2"\n[planner]\ntime_limit_s = 2.5\n')
    config = load_config(path)
    assert (config.robot_id, config.planner.time_limit_s, config.planner.cost) == ("kitchen-2", 2.5, "upc")


def test_the_printed_config_reads_back_to_the_same_values() -> None:
    config = load_config()
    assert parse_config(tomllib.loads(to_toml(config.to_dict()))) == config


def test_the_simulated_speed_may_be_max() -> None:
    config = load_config(overrides={"sim": {"speed": "max"}})
    assert config.sim.speed is None
    assert config.to_dict()["sim"]["speed"] == "max"
    assert parse_config(tomllib.loads(to_toml(config.to_dict()))) == config


BAD: list[tuple[dict[str, Any], str]] = [
    ({"planner": {"time_limit_s": -1}}, "planner.time_limit_s: -1 is out of range; allowed [0.01, 600]"),
    (
        {"planner": {"time_limit_s": "fast"}},
        "planner.time_limit_s: expected a number in [0.01, 600], got 'fast'",
    ),
    ({"planner": {"seed": 1.5}}, "planner.seed: expected an integer in [0, 2147483647], got 1.5"),
    ({"planner": {"allow_rotation": 1}}, "planner.allow_rotation: expected true or false, got 1"),
    ({"planner": {"cost": "cheap"}}, "planner.cost: 'cheap' is not one of bpc, upc, ec"),
    ({"backend": "cloud"}, "backend: 'cloud' is not one of sim, hardware"),
    (
        {"robot_id": "a/b"},
        "robot_id: 'a/b' is not allowed; use 1-64 letters, digits, '_' or '-' (a Zenoh key chunk)",
    ),
    (
        {"zenoh": {"listen": ["127.0.0.1:3474"]}},
        "zenoh.listen[0]: '127.0.0.1:3474' is not a Zenoh endpoint like tcp/127.0.0.1:3474 "
        "(protocol tcp, udp, tls, quic or ws; port 1-65535)",
    ),
    (
        {"zenoh": {"connect": ["tcp/127.0.0.1:70000"]}},
        "zenoh.connect[0]: 'tcp/127.0.0.1:70000' is not a Zenoh endpoint like tcp/127.0.0.1:3474 "
        "(protocol tcp, udp, tls, quic or ws; port 1-65535)",
    ),
    ({"zenoh": {"listen": "tcp/127.0.0.1:3474"}}, "zenoh.listen: expected a list, got 'tcp/127.0.0.1:3474'"),
    ({"cell": {"tray_size_mm": [332]}}, "cell.tray_size_mm: expected 2 values, got 1"),
    ({"cell": {"tray_size_mm": [332, 10]}}, "cell.tray_size_mm[1]: 10 is out of range; allowed [50, 2000]"),
    (
        {"cell": {"counter_region_m": [0.3, 0.2, 0.1, 0.5]}},
        "cell.counter_region_m: [0.3, 0.2, 0.1, 0.5] is not [x_min, y_min, x_max, y_max] with min < max",
    ),
    ({"daemon": {"joints_rate_hz": 5}}, "daemon.joints_rate_hz: 5 is out of range; allowed [20, 500]"),
    ({"sim": {"speed": float("inf")}}, "sim.speed: inf is out of range; allowed [0.1, 1000]"),
    ({"sim": {"speed": "fast"}}, "sim.speed: expected \"max\" or a number in [0.1, 1000], got 'fast'"),
    ({"sim": {"transport": "usb"}}, "sim.transport: 'usb' is not one of inprocess, pty"),
    ({"sim": {"world": "gazebo"}}, "sim.world: 'gazebo' is not one of kinematic, mujoco"),
    (
        {"mug_types": {"tiny": {"diameter_mm": 80, "width_mm": 70, "height_mm": 50, "mass_kg": 0.1}}},
        "mug_types.tiny.width_mm: 70 is smaller than diameter_mm 80; the width includes the handle",
    ),
    ({"mug_types": {"Big": {}}}, "mug_types.Big: mug type names are 1-32 lower-case letters, digits or '_'"),
    (
        {"grasp": {"force_threshold_n": True}},
        "grasp.force_threshold_n: expected a number in [0.1, 50], got true",
    ),
    (
        {"grasp": {"forse": 1.0}},
        "grasp.forse: unknown key in grasp (known keys: force_threshold_n, max_attempts, min_aperture_m)",
    ),
    ({"camera": {"position_m": [1.0, 0.0]}}, "camera.position_m: expected 3 values, got 2"),
    ({"camera": {"calibration_file": 3}}, "camera.calibration_file: expected a string, got 3"),
    ({"camera": {"fovy_deg": 130.0}}, "camera.fovy_deg: 130 is out of range; allowed [10, 120]"),
    ({"camera": {"pitch_rad": 0.0}}, "camera.pitch_rad: 0 does not look down; allowed (0, 1.5708)"),
    ({"recording": "here"}, "recording: expected a table, got 'here'"),
]


@pytest.mark.parametrize(
    ("override", "message"), BAD, ids=[m.split(":")[0] + "-" + str(i) for i, (_, m) in enumerate(BAD)]
)
def test_a_bad_value_fails_with_its_field_and_allowed_range(override: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(overrides=override)
    assert str(info.value) == message


def test_a_missing_key_is_named() -> None:
    data = tomllib.loads(to_toml(load_config().to_dict()))
    del data["grasp"]["min_aperture_m"]
    with pytest.raises(ConfigError, match=r"^grasp\.min_aperture_m: missing; add it to the config file$"):
        parse_config(data)


def test_an_unknown_top_level_section_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"^zenho: unknown key in the top level \(known keys: "):
        load_config(overrides={"zenho": {"listen": []}})


def test_an_empty_mug_catalogue_is_refused() -> None:
    data = tomllib.loads(to_toml(load_config().to_dict()))
    data["mug_types"] = {}
    with pytest.raises(ConfigError, match=r"^mug_types: the catalogue is empty"):
        parse_config(data)


def test_a_file_that_is_not_toml_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("robot_id = \n")
    with pytest.raises(ConfigError, match=rf"^config file {path} is not valid TOML: "):
        load_config(path)


def test_a_missing_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "none.toml"
    with pytest.raises(ConfigError, match=rf"^cannot read config file {path}: No such file or directory$"):
        load_config(path)


def test_config_show_exits_2_with_one_line_and_no_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("[daemon]\ngripper_rate_hz = 10\n")
    assert main(["config", "show", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == "dishbot config: error: daemon.gripper_rate_hz: 10 is out of range; allowed [50, 500]\n"


def test_config_show_prints_the_effective_toml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "robot.toml"
    path.write_text('robot_id = "r2"\n')
    assert main(["config", "show", "--config", str(path)]) == 0
    shown = tomllib.loads(capsys.readouterr().out)
    assert shown["robot_id"] == "r2"
    assert shown["mug_types"]["small"]["width_mm"] == 100


def test_the_cell_and_catalogue_are_the_description_types_the_planners_and_worlds_take() -> None:
    config = load_config(
        overrides={"planner": {"tolerance_mm": 14}, "cell": {"tray_origin_m": [0.35, -0.18]}}
    )
    assert isinstance(config.cell, CellLayout)
    assert config.cell.tray == Tray(origin_m=(0.35, -0.18), size_mm=(332, 374))
    assert config.cell.camera == CameraSpec(640, 480, 72.0, (0.115, 1.325, 0.80), -1.570796, 0.959931)
    assert config.cell.tolerance_mm == 14  # the footprint tolerance the planner packs with
    assert config.mug_catalogue() == thesis.MUG_TYPES
    shown = config.to_dict()
    assert shown["cell"]["tray_origin_m"] == [0.35, -0.18]
    assert list(shown["camera"]) == [
        "width",
        "height",
        "fovy_deg",
        "position_m",
        "yaw_rad",
        "pitch_rad",
        "calibration_file",
        "frame_timeout_s",
        "max_frame_age_s",
        "frame_retries",
    ]


def test_every_job_state_has_a_time_bound_and_leaves_may_have_shorter_ones() -> None:
    bounds = load_config(overrides={"daemon": {"state_bounds_s": {"flip.turn": 20.0}}}).daemon
    assert bounds.state_bound_s("detect") == 60.0
    assert bounds.state_bound_s("flip.turn") == 20.0
    assert bounds.state_bound_s("flip.transit") is None
    for bad, message in (
        ({"fly": 3}, "daemon.state_bounds_s.fly: 'fly' is not a job state or leaf"),
        (
            {"flip.turn": 500},
            "daemon.state_bounds_s.flip.turn: 500 s is longer than flip's own bound of 120 s",
        ),
        ({"detect": 0}, "daemon.state_bounds_s.detect: 0 is out of range; allowed [1, 3600]"),
    ):
        with pytest.raises(ConfigError, match=f"^{re.escape(message)}"):
            load_config(overrides={"daemon": {"state_bounds_s": bad}})


def test_the_camera_frame_limits_are_read_and_checked() -> None:
    camera = load_config(overrides={"camera": {"frame_timeout_s": 0.5, "frame_retries": 0}}).camera
    assert (camera.frames.timeout_s, camera.frames.max_age_s, camera.frames.retries) == (0.5, 1.0, 0)
    with pytest.raises(ConfigError, match=r"^camera.frame_retries: 11 is out of range"):
        load_config(overrides={"camera": {"frame_retries": 11}})


def test_the_device_sections_are_the_drivers_and_perceptions_own_settings() -> None:
    """``[hardware.fsr]``, ``[hardware.health]`` and ``[camera]``'s frame keys are read straight into the
    types the reader, the chain's health watch and the observer take, with the ranges those types declare."""
    config = load_config(
        overrides={
            "hardware": {"fsr": {"gain": 2.5, "release_n": 0.4}, "health": {"corrupt_window": 20}},
            "camera": {"max_frame_age_s": 0.25},
        }
    )
    hw = config.hardware
    assert hw.fsr == FsrSettings("/dev/dishbot-fsr", gain=2.5, threshold_n=1.0, release_n=0.4)
    assert hw.health == HealthLimits(corrupt_window=20)
    assert config.camera.frames == FrameLimits(max_age_s=0.25)
    for override, message in (
        ({"hardware": {"fsr": {"gain": 0}}}, "hardware.fsr.gain: 0 is out of range; allowed [0.001, 1000]"),
        (
            {"hardware": {"health": {"temperature_warn_c": 75.0}}},
            "hardware.health.temperature_warn_c: 75 must be below temperature_limit_c 70",
        ),
        (
            {"hardware": {"health": {"voltage_min_v": 13.5}}},
            "hardware.health.voltage_max_v: 14 must be above voltage_min_v 13.5 by more than twice "
            "voltage_warn_margin_v 0.5",
        ),
        ({"camera": {"frame_timeout_s": 0}}, "camera.frame_timeout_s: 0 is out of range; allowed [0.05, 60]"),
    ):
        with pytest.raises(ConfigError) as e:
            load_config(overrides=override)
        assert str(e.value) == message


def test_settings_built_in_code_keep_the_config_files_rules() -> None:
    with pytest.raises(Invalid, match=r"^release_n: 2 must be below threshold_n 1 \(the hysteresis"):
        FsrSettings("/dev/x", threshold_n=1.0, release_n=2.0)
    with pytest.raises(Invalid, match=r"^temperature_warn_c: 80 must be below temperature_limit_c 70$"):
        HealthLimits(temperature_warn_c=80.0)


def test_the_default_set_down_is_the_cycle_planners() -> None:
    from planning.motion.scene import SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S

    arm = load_config().arm
    assert (arm.set_down_slow_m, arm.set_down_speed_m_s) == (SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S)
