"""dishbot's configuration: embedded TOML defaults, optional overrides from a file, validated once at load.

Every value is checked when the file is read, so a bad field fails at start-up with its dotted name and the
allowed range (``ConfigError``, exit 2) instead of deep inside a running job. The result is a tree of frozen
dataclasses, and the description types where the config describes the cell (``Config.cell`` is the one
``description.cell.CellLayout``, ``Config.mug_types`` the catalogue's ``MugSpec`` entries), so they travel to
the planners and worlds as they are. ``Config.to_dict()`` gives the effective values back in the file's
layout (for ``dishbot config show`` and the recording's session header).
"""

from __future__ import annotations

import ipaddress
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

from daemon.errors import ConfigError
from daemon.security import ZenohConfig, check_files, check_key, parse_zenoh
from daemon.security import check_endpoint as check_endpoint  # where the verbs have always found it
from description.camera import MAX_FOVY_DEG, MIN_FOVY_DEG, CameraSpec
from description.cell import CellLayout, Tray
from description.errors import InvalidCell
from description.thesis import JOINT_SERVOS, MugSpec, mug_catalogue
from drivers.dynamixel.tables import BAUD_CODES_1, BAUD_CODES_2, MODELS
from planning.placement import FOOTPRINTS, METHODS
from recorder.settings import RecordingConfig
from statechart.chart import JOB_LEAVES, JOB_STATES, top_level

_ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_BACKENDS = ("sim", "hardware")
_WORLDS = ("kinematic", "mujoco")
_TRANSPORTS = ("inprocess", "pty")
PLANNER_FITNESS = ("rf", "ws")
PLANNER_COSTS = ("bpc", "upc", "ec")
_ENERGY_MODELS = ("thesis", "dynamics")
_CAMERAS = ("realsense", "zenoh", "none")
RECORDING_COMPRESSIONS = ("zstd", "lz4", "none")
_LISTEN = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


@dataclass(frozen=True, slots=True)
class FoxgloveConfig:
    """Foxglove's well-known channels in the recordings; the live WebSocket server (``listen = ""``: off)."""

    channels: bool
    listen: str
    insecure: bool
    depth_hz: float

    @property
    def address(self) -> tuple[str, int] | None:
        """The server's host and port, or None when it is off."""
        return parse_listen(self.listen, "foxglove.listen") if self.listen else None


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """The depth camera's calibration file (``dishbot calibrate`` writes it), overriding the pose in
    ``[camera]``, and what a frame must meet: arrive within ``frame_timeout_s``, be at most
    ``max_frame_age_s`` old, else be tried again up to ``frame_retries`` times before the job faults. The
    camera itself (image size, field of view, pose) is part of the cell: ``Config.cell.camera``."""

    calibration_file: Path | None
    frame_timeout_s: float = 2.0
    max_frame_age_s: float = 1.0
    frame_retries: int = 2


@dataclass(frozen=True, slots=True)
class PlannerConfig:
    """Placement planner settings; a ``start`` command may override method, fitness, cost and time limit."""

    method: str
    fitness: str
    cost: str
    time_limit_s: float
    seed: int
    tolerance_mm: int
    allow_rotation: bool
    energy_model: str
    footprint: str = "rect"  # "rect" (the thesis's rectangles) or "mug" (brim disc plus handle)


@dataclass(frozen=True, slots=True)
class DaemonConfig:
    """Telemetry rates and command limits of the daemon process, and how long each job state may last.

    ``state_bounds_s`` maps every top-level job state (``detect``, ``plan``, ...) to the longest it may stay
    entered, and may add bounds of their own for leaves (``"flip.turn"``); a state past its bound faults
    the job (``state detect exceeded its 60 s bound``) instead of stalling it silently, and the systemd
    watchdog is not pinged meanwhile."""

    state_rate_hz: float
    joints_rate_hz: float
    gripper_rate_hz: float
    max_command_bytes: int
    drop_check_period_s: float
    state_bounds_s: Mapping[str, float] = field(default_factory=lambda: dict.fromkeys(JOB_STATES, 60.0))

    def state_bound_s(self, state: str) -> float | None:
        """The bound of a job state or leaf (None: it has none of its own)."""
        return self.state_bounds_s.get(state)


@dataclass(frozen=True, slots=True)
class GraspConfig:
    """When a closed gripper counts as holding a mug (§4.3.1: a force threshold and a minimum aperture)."""

    force_threshold_n: float
    min_aperture_m: float
    max_attempts: int


@dataclass(frozen=True, slots=True)
class SimConfig:
    """The simulated cell: which world, how it reaches the simulated devices, how fast against the wall
    clock (None: as fast as the machine allows), the detector's noise."""

    world: str
    transport: str
    speed: float | None
    seed: int
    detection_noise_m: float
    joint_speed_rad_s: float
    start_q_rad: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class ArmConfig:
    """The arm's position correction (``dishbot calibrate``), applied by the cycle planner."""

    calibration_file: Path | None


@dataclass(frozen=True, slots=True)
class ServoConfig:
    """The servo driving one joint (or the gripper): its bus id and model."""

    joint: str
    id: int
    model: str


@dataclass(frozen=True, slots=True)
class HardwareGripperConfig:
    """The real gripper: its angle-to-aperture map (empty: the arm model's geometry) and overload policy."""

    aperture_map: tuple[tuple[float, float], ...]
    grip_limit: float
    grip_limit_backoff: float
    overload_retries: int


@dataclass(frozen=True, slots=True)
class FsrConfig:
    """The FSR Arduino's port and the reader's calibration (``dishbot fsr calibrate`` prints these)."""

    port: str
    gain: float
    threshold_n: float
    release_n: float
    debounce_s: float
    stale_after_s: float


@dataclass(frozen=True, slots=True)
class HealthConfig:
    """How the servos' health is watched: every ``poll_period_s`` their supply voltage (a warning
    ``voltage_warn_margin_v`` inside ``voltage_min_v``..``voltage_max_v``, a fault outside) and temperature
    (a warning from ``temperature_warn_c``, a fault past ``temperature_limit_c``); and when the bus calls a
    servo's answers too corrupt (more than ``corrupt_rate_max`` of its last ``corrupt_window``)."""

    poll_period_s: float
    voltage_min_v: float
    voltage_max_v: float
    voltage_warn_margin_v: float
    temperature_warn_c: float
    temperature_limit_c: float
    corrupt_rate_max: float
    corrupt_window: int


@dataclass(frozen=True, slots=True)
class ZenohCameraConfig:
    """A depth camera whose node publishes frames on Zenoh (``camera = "zenoh"``, ``daemon.zenoh_camera``):
    the node's endpoint and the key its frames come on."""

    connect: str
    key: str


@dataclass(frozen=True, slots=True)
class HardwareConfig:
    """The robot's devices, used when ``backend = "hardware"``: the servo bus, each joint's servo, the
    gripper, the FSR and the depth camera."""

    servo_port: str
    baudrate: int
    protocol: int
    retries: int
    read_timeout_s: float
    servos: tuple[ServoConfig, ...]
    gripper: HardwareGripperConfig
    fsr: FsrConfig
    camera: str
    camera_serial: str
    zenoh_camera: ZenohCameraConfig
    health: HealthConfig

    def servo(self, joint: str) -> ServoConfig:
        for servo in self.servos:
            if servo.joint == joint:
                return servo
        raise KeyError(joint)


@dataclass(frozen=True, slots=True)
class Config:
    """The effective configuration of one daemon process."""

    robot_id: str
    backend: str
    zenoh: ZenohConfig
    recording: RecordingConfig
    foxglove: FoxgloveConfig
    # [cell] with [camera]'s image and pose (cell.camera); its tolerance is planner.tolerance_mm.
    cell: CellLayout
    camera: CameraConfig
    mug_types: tuple[MugSpec, ...]
    planner: PlannerConfig
    daemon: DaemonConfig
    grasp: GraspConfig
    sim: SimConfig
    arm: ArmConfig
    hardware: HardwareConfig

    def mug_type(self, name: str) -> MugSpec:
        for mug in self.mug_types:
            if mug.name == name:
                return mug
        raise KeyError(name)

    def mug_catalogue(self) -> dict[str, MugSpec]:
        """The configured mug types by name: what the planners, the detector and the simulated worlds take."""
        return mug_catalogue(self.mug_types)

    def to_dict(self) -> dict[str, Any]:
        """The effective values as plain TOML/JSON types, in the file's layout."""
        out: dict[str, Any] = _plain(self)
        out["cell"] = _cell_table(self.cell)
        out["camera"] = {
            **_plain(self.cell.camera),
            "calibration_file": _plain(self.camera.calibration_file),
            "frame_timeout_s": self.camera.frame_timeout_s,
            "max_frame_age_s": self.camera.max_frame_age_s,
            "frame_retries": self.camera.frame_retries,
        }
        out["recording"]["compression"] = self.recording.compression or "none"
        out["mug_types"] = {m["name"]: {k: v for k, v in m.items() if k != "name"} for m in out["mug_types"]}
        hw = out["hardware"]
        hw["servos"] = {s["joint"]: {"id": s["id"], "model": s["model"]} for s in hw["servos"]}
        out["sim"]["speed"] = "max" if self.sim.speed is None else self.sim.speed
        if out["zenoh"]["auth"]["password"]:  # shown and recorded everywhere: never the secret itself
            out["zenoh"]["auth"]["password"] = "(hidden)"
        return out


def default_text() -> str:
    """The embedded defaults, comments included."""
    return resources.files("daemon").joinpath("default_config.toml").read_text(encoding="utf-8")


def load_config(path: Path | None = None, *, overrides: Mapping[str, Any] | None = None) -> Config:
    """The defaults, updated by the TOML file at ``path`` and then by ``overrides`` (nested tables merge).

    The security files named in ``[zenoh]`` are taken relative to the file's folder (so a folder written by
    ``dishbot security init`` works wherever it is copied) and must be readable."""
    data = tomllib.loads(default_text())
    if path is not None:
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise ConfigError(f"cannot read config file {path}: {e.strerror}") from e
        try:
            user = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"config file {path} is not valid TOML: {e}") from e
        data = _merge(data, user)
    if overrides:
        data = _merge(data, overrides)
    config = parse_config(data)
    if path is not None:
        config = replace(config, zenoh=config.zenoh.resolved(path.parent))
    check_files(config.zenoh)
    return config


def parse_config(data: Mapping[str, Any]) -> Config:
    """Validate a complete configuration mapping (all sections present)."""
    root = _Section(data, "")
    robot_id = root.text("robot_id")
    if not _ROBOT_ID.match(robot_id):
        raise ConfigError(
            f"robot_id: {robot_id!r} is not allowed; use 1-64 letters, digits, '_' or '-' (a Zenoh key chunk)"
        )
    backend = root.choice("backend", _BACKENDS)
    zenoh = _zenoh(root.section("zenoh"))
    recording = _recording(root.section("recording"))
    planner = _planner(root.section("planner"))
    camera_spec, camera = _camera(root.section("camera"))
    config = Config(
        robot_id=robot_id,
        backend=backend,
        zenoh=zenoh,
        recording=recording,
        foxglove=_foxglove(root.section("foxglove")),
        cell=_cell(root.section("cell"), camera_spec, tolerance_mm=planner.tolerance_mm),
        camera=camera,
        mug_types=_mug_types(root.section("mug_types")),
        planner=planner,
        daemon=_daemon(root.section("daemon")),
        grasp=_grasp(root.section("grasp")),
        sim=_sim(root.section("sim")),
        arm=_arm(root.section("arm")),
        hardware=_hardware(root.section("hardware")),
    )
    root.finish()
    return config


def to_toml(data: Mapping[str, Any]) -> str:
    """A TOML document for a mapping of the types ``Config.to_dict`` produces."""
    lines: list[str] = []
    _emit_table(data, [], lines)
    return "\n".join(lines).strip() + "\n"


def _zenoh(s: _Section) -> ZenohConfig:
    return parse_zenoh(s.everything(), "zenoh")


def _recording(s: _Section) -> RecordingConfig:
    compression = s.choice("compression", RECORDING_COMPRESSIONS)
    cfg = RecordingConfig(
        dir=Path(s.text("dir")),
        chunk_size_bytes=s.integer("chunk_size_bytes", 1024, 16 * 1024 * 1024),
        compression=None if compression == "none" else compression,
        idle_telemetry_hz=s.number("idle_telemetry_hz", 0.01, 100.0),
        idle_file_s=s.number("idle_file_s", 10.0, 7 * 86400.0),
        job_tail_s=s.number("job_tail_s", 0.0, 60.0),
        max_total_mb=s.integer("max_total_mb", 0, 10**7),
        max_age_days=s.number("max_age_days", 0.0, 3650.0),
    )
    s.finish()
    return cfg


def _foxglove(s: _Section) -> FoxgloveConfig:
    cfg = FoxgloveConfig(
        channels=s.flag("channels"),
        listen=s.string("listen"),
        insecure=s.flag("insecure"),
        depth_hz=s.number("depth_hz", 0.01, 30.0),
    )
    if cfg.listen:
        check_foxglove_listen(cfg.listen, "foxglove.listen", insecure=cfg.insecure)
    s.finish()
    return cfg


def _cell(s: _Section, camera: CameraSpec, *, tolerance_mm: int) -> CellLayout:
    """``[cell]`` with the camera of ``[camera]``: the one cell layout (its own checks name the field)."""
    region = s.floats("counter_region_m", 4, -2.0, 2.0)
    center = s.floats("flip_area_center_m", 2, -2.0, 2.0)
    origin = s.floats("tray_origin_m", 2, -2.0, 2.0)
    size = s.integers("tray_size_mm", 2, 50, 2000)
    try:
        cell = CellLayout(
            counter_region_m=(region[0], region[1], region[2], region[3]),
            flip_area_center_m=(center[0], center[1]),
            flip_area_radius_m=s.number("flip_area_radius_m", 0.01, 1.0),
            tray=Tray(origin_m=(origin[0], origin[1]), size_mm=(size[0], size[1])),
            camera=camera,
            table_height_above_floor_m=s.number("table_height_above_floor_m", 0.3, 2.0),
            tolerance_mm=tolerance_mm,
        )
    except InvalidCell as e:
        raise ConfigError(str(e)) from e
    s.finish()
    return cell


def _cell_table(cell: CellLayout) -> dict[str, Any]:
    """The ``[cell]`` table of a cell layout, as the config file has it (the inverse of ``_cell``)."""
    return {
        "counter_region_m": list(cell.counter_region_m),
        "flip_area_center_m": list(cell.flip_area_center_m),
        "flip_area_radius_m": cell.flip_area_radius_m,
        "tray_origin_m": list(cell.tray.origin_m),
        "tray_size_mm": list(cell.tray.size_mm),
        "table_height_above_floor_m": cell.table_height_above_floor_m,
    }


def _camera(s: _Section) -> tuple[CameraSpec, CameraConfig]:
    position = s.floats("position_m", 3, -5.0, 5.0)
    calibration = s.string("calibration_file")
    try:
        spec = CameraSpec(
            width=s.integer("width", 16, 4096),
            height=s.integer("height", 16, 4096),
            fovy_deg=s.number("fovy_deg", MIN_FOVY_DEG, MAX_FOVY_DEG),
            position_m=(position[0], position[1], position[2]),
            yaw_rad=s.number("yaw_rad", -2 * math.pi, 2 * math.pi),
            pitch_rad=s.number("pitch_rad", -math.pi / 2, math.pi / 2),
        )
    except InvalidCell as e:
        raise ConfigError(str(e)) from e
    camera = CameraConfig(
        calibration_file=Path(calibration) if calibration else None,
        frame_timeout_s=s.number("frame_timeout_s", 0.05, 60.0),
        max_frame_age_s=s.number("max_frame_age_s", 0.01, 60.0),
        frame_retries=s.integer("frame_retries", 0, 10),
    )
    s.finish()
    return spec, camera


def _mug_types(s: _Section) -> tuple[MugSpec, ...]:
    mugs = []
    for name in s.names():
        if not re.match(r"^[a-z][a-z0-9_]{0,31}$", name):
            raise ConfigError(f"mug_types.{name}: mug type names are 1-32 lower-case letters, digits or '_'")
        m = s.section(name)
        mug = MugSpec(
            name=name,
            diameter_mm=m.integer("diameter_mm", 20, 300),
            width_mm=m.integer("width_mm", 20, 400),
            height_mm=m.integer("height_mm", 20, 400),
            mass_kg=m.number("mass_kg", 0.01, 2.0),
        )
        if mug.width_mm < mug.diameter_mm:
            raise ConfigError(
                f"mug_types.{name}.width_mm: {mug.width_mm} is smaller than diameter_mm {mug.diameter_mm}; "
                "the width includes the handle"
            )
        m.finish()
        mugs.append(mug)
    if not mugs:
        raise ConfigError("mug_types: the catalogue is empty; define at least one [mug_types.NAME] table")
    return tuple(mugs)


def _planner(s: _Section) -> PlannerConfig:
    cfg = PlannerConfig(
        method=s.choice("method", METHODS),
        fitness=s.choice("fitness", PLANNER_FITNESS),
        cost=s.choice("cost", PLANNER_COSTS),
        time_limit_s=s.number("time_limit_s", 0.01, 600.0),
        seed=s.integer("seed", 0, 2**31 - 1),
        tolerance_mm=s.integer("tolerance_mm", 0, 100),
        allow_rotation=s.flag("allow_rotation"),
        energy_model=s.choice("energy_model", _ENERGY_MODELS),
        footprint=s.choice("footprint", FOOTPRINTS),
    )
    s.finish()
    return cfg


def _daemon(s: _Section) -> DaemonConfig:
    cfg = DaemonConfig(
        state_rate_hz=s.number("state_rate_hz", 1.0, 100.0),
        joints_rate_hz=s.number("joints_rate_hz", 20.0, 500.0),
        gripper_rate_hz=s.number("gripper_rate_hz", 50.0, 500.0),
        max_command_bytes=s.integer("max_command_bytes", 256, 1024 * 1024),
        drop_check_period_s=s.number("drop_check_period_s", 0.001, 0.5),
        state_bounds_s=_state_bounds(s.section("state_bounds_s")),
    )
    s.finish()
    return cfg


def _state_bounds(s: _Section) -> dict[str, float]:
    """``[daemon.state_bounds_s]``: a bound for every top-level job state, optionally for leaves too."""
    bounds = {}
    for name in s.names():
        if name not in JOB_STATES and name not in JOB_LEAVES:
            raise ConfigError(
                f"{s._name(name)}: {name!r} is not a job state or leaf (states: {', '.join(JOB_STATES)}; "
                'leaves such as "flip.turn")'
            )
        bounds[name] = s.number(name, 1.0, 3600.0)
    missing = [state for state in JOB_STATES if state not in bounds]
    if missing:
        raise ConfigError(f"{s._name(missing[0])}: missing; every job state needs a bound")
    for leaf, bound in bounds.items():
        state = top_level(leaf)
        if leaf != state and bound > bounds[state]:
            raise ConfigError(
                f"{s._name(leaf)}: {bound:g} s is longer than {state}'s own bound of {bounds[state]:g} s"
            )
    s.finish()
    return bounds


def _grasp(s: _Section) -> GraspConfig:
    cfg = GraspConfig(
        force_threshold_n=s.number("force_threshold_n", 0.1, 50.0),
        min_aperture_m=s.number("min_aperture_m", 0.0, 0.2),
        max_attempts=s.integer("max_attempts", 1, 10),
    )
    s.finish()
    return cfg


def _sim(s: _Section) -> SimConfig:
    cfg = SimConfig(
        world=s.choice("world", _WORLDS),
        transport=s.choice("transport", _TRANSPORTS),
        speed=s.speed("speed", 0.1, 1000.0),
        seed=s.integer("seed", 0, 2**31 - 1),
        detection_noise_m=s.number("detection_noise_m", 0.0, 0.05),
        joint_speed_rad_s=s.number("joint_speed_rad_s", 0.05, 10.0),
        start_q_rad=s.floats("start_q_rad", 5, -math.pi, math.pi),
    )
    s.finish()
    return cfg


def _arm(s: _Section) -> ArmConfig:
    calibration = s.string("calibration_file")
    cfg = ArmConfig(calibration_file=Path(calibration) if calibration else None)
    s.finish()
    return cfg


def _hardware(s: _Section) -> HardwareConfig:
    protocol = s.integer("protocol", 1, 2)
    rates = BAUD_CODES_1 if protocol == 1 else BAUD_CODES_2
    baudrate = s.integer("baudrate", min(rates), max(rates))
    if baudrate not in rates:
        allowed = ", ".join(str(r) for r in sorted(rates))
        raise ConfigError(f"hardware.baudrate: {baudrate} is not a Protocol {protocol}.0 rate; use {allowed}")
    cfg = HardwareConfig(
        servo_port=s.text("servo_port"),
        baudrate=baudrate,
        protocol=protocol,
        retries=s.integer("retries", 0, 10),
        read_timeout_s=s.number("read_timeout_s", 0.001, 1.0),
        servos=_servos(s.section("servos"), protocol),
        gripper=_hardware_gripper(s.section("gripper")),
        fsr=_fsr(s.section("fsr")),
        camera=s.choice("camera", _CAMERAS),
        camera_serial=s.string("camera_serial"),
        zenoh_camera=_zenoh_camera(s.section("zenoh_camera")),
        health=_health(s.section("health")),
    )
    s.finish()
    return cfg


def _health(s: _Section) -> HealthConfig:
    cfg = HealthConfig(
        poll_period_s=s.number("poll_period_s", 0.05, 60.0),
        voltage_min_v=s.number("voltage_min_v", 0.0, 30.0),
        voltage_max_v=s.number("voltage_max_v", 0.0, 30.0),
        voltage_warn_margin_v=s.number("voltage_warn_margin_v", 0.0, 5.0),
        temperature_warn_c=s.number("temperature_warn_c", 0.0, 100.0),
        temperature_limit_c=s.number("temperature_limit_c", 0.0, 100.0),
        corrupt_rate_max=s.number("corrupt_rate_max", 0.0, 1.0),
        corrupt_window=s.integer("corrupt_window", 1, 10_000),
    )
    if not cfg.voltage_min_v + 2 * cfg.voltage_warn_margin_v < cfg.voltage_max_v:
        raise ConfigError(
            f"hardware.health.voltage_max_v: {cfg.voltage_max_v:g} must be above voltage_min_v "
            f"{cfg.voltage_min_v:g} by more than twice voltage_warn_margin_v {cfg.voltage_warn_margin_v:g}"
        )
    if not cfg.temperature_warn_c < cfg.temperature_limit_c:
        raise ConfigError(
            f"hardware.health.temperature_warn_c: {cfg.temperature_warn_c:g} must be below "
            f"temperature_limit_c {cfg.temperature_limit_c:g}"
        )
    s.finish()
    return cfg


def _servos(s: _Section, protocol: int) -> tuple[ServoConfig, ...]:
    servos = []
    for joint, _ in JOINT_SERVOS:
        t = s.section(joint)
        model = t.choice("model", tuple(MODELS))
        if MODELS[model].protocol != protocol:
            raise ConfigError(
                f"hardware.servos.{joint}.model: {model} speaks Protocol {MODELS[model].protocol}.0 but "
                f"hardware.protocol is {protocol}"
            )
        servos.append(ServoConfig(joint, t.integer("id", 0, 252), model))
        t.finish()
    s.finish()
    seen: dict[int, str] = {}
    for servo in servos:
        if servo.id in seen:
            raise ConfigError(
                f"hardware.servos.{servo.joint}.id: {servo.id} is already the id of {seen[servo.id]}; "
                "every servo on the bus needs its own id"
            )
        seen[servo.id] = servo.joint
    return tuple(servos)


def _hardware_gripper(s: _Section) -> HardwareGripperConfig:
    points = []
    for i, pair in enumerate(s._list("aperture_map", None)):
        name = f"hardware.gripper.aperture_map[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            raise ConfigError(f"{name}: expected [servo angle rad, aperture m], got {_show(pair)}")
        points.append(
            (_check_number(pair[0], name, -math.pi, math.pi), _check_number(pair[1], name, 0.0, 0.3))
        )
    angles = [a for a, _ in points]
    if points and (len(points) < 2 or angles != sorted(set(angles))):
        raise ConfigError(
            "hardware.gripper.aperture_map: needs at least two [angle, aperture] points in strictly "
            "increasing angle (or [] for the arm model's geometry)"
        )
    cfg = HardwareGripperConfig(
        aperture_map=tuple(points),
        grip_limit=s.number("grip_limit", 0.05, 1.0),
        grip_limit_backoff=s.number("grip_limit_backoff", 0.1, 0.95),
        overload_retries=s.integer("overload_retries", 0, 10),
    )
    s.finish()
    return cfg


def _zenoh_camera(s: _Section) -> ZenohCameraConfig:
    key = check_key(s._get("key"), "hardware.zenoh_camera.key")
    connect = check_endpoint(s._get("connect"), "hardware.zenoh_camera.connect")
    cfg = ZenohCameraConfig(connect=connect, key=key)
    s.finish()
    return cfg


def _fsr(s: _Section) -> FsrConfig:
    cfg = FsrConfig(
        port=s.text("port"),
        gain=s.number("gain", 0.001, 1000.0),
        threshold_n=s.number("threshold_n", 0.05, 50.0),
        release_n=s.number("release_n", 0.0, 50.0),
        debounce_s=s.number("debounce_s", 0.0, 1.0),
        stale_after_s=s.number("stale_after_s", 0.02, 5.0),
    )
    if cfg.release_n >= cfg.threshold_n:
        raise ConfigError(
            f"hardware.fsr.release_n: {cfg.release_n:g} must be below threshold_n {cfg.threshold_n:g} "
            "(the hysteresis of the grasp detection)"
        )
    s.finish()
    return cfg


class _Section:
    """Typed, range-checked access to one TOML table; ``finish()`` rejects keys nobody asked for."""

    def __init__(self, data: Mapping[str, Any], prefix: str) -> None:
        self._data = data
        self._prefix = prefix
        self._seen: set[str] = set()

    def _name(self, key: str) -> str:
        return f"{self._prefix}{key}"

    def _get(self, key: str) -> Any:
        self._seen.add(key)
        if key not in self._data:
            raise ConfigError(f"{self._name(key)}: missing; add it to the config file")
        return self._data[key]

    def names(self) -> list[str]:
        return list(self._data)

    def everything(self) -> Mapping[str, Any]:
        """The whole table, for a parser of its own (which rejects unknown keys itself)."""
        self._seen.update(self._data)
        return self._data

    def section(self, key: str) -> _Section:
        value = self._get(key)
        if not isinstance(value, Mapping):
            raise ConfigError(f"{self._name(key)}: expected a table, got {_show(value)}")
        return _Section(value, f"{self._name(key)}.")

    def text(self, key: str) -> str:
        value = self._get(key)
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{self._name(key)}: expected a non-empty string, got {_show(value)}")
        return value

    def string(self, key: str) -> str:
        value = self._get(key)
        if not isinstance(value, str):
            raise ConfigError(f"{self._name(key)}: expected a string, got {_show(value)}")
        return value

    def choice(self, key: str, allowed: tuple[str, ...]) -> str:
        value = self._get(key)
        if value not in allowed:
            raise ConfigError(f"{self._name(key)}: {_show(value)} is not one of {', '.join(allowed)}")
        return str(value)

    def flag(self, key: str) -> bool:
        value = self._get(key)
        if not isinstance(value, bool):
            raise ConfigError(f"{self._name(key)}: expected true or false, got {_show(value)}")
        return value

    def number(self, key: str, lo: float, hi: float) -> float:
        return _check_number(self._get(key), self._name(key), lo, hi)

    def speed(self, key: str, lo: float, hi: float) -> float | None:
        """``"max"`` (None) or a number in [lo, hi]."""
        value = self._get(key)
        if value == "max":
            return None
        if isinstance(value, str):
            raise ConfigError(
                f'{self._name(key)}: expected "max" or a number in [{lo:g}, {hi:g}], got {value!r}'
            )
        return _check_number(value, self._name(key), lo, hi)

    def integer(self, key: str, lo: int, hi: int) -> int:
        return _check_integer(self._get(key), self._name(key), lo, hi)

    def floats(self, key: str, n: int, lo: float, hi: float) -> tuple[float, ...]:
        items = self._list(key, n)
        return tuple(_check_number(v, f"{self._name(key)}[{i}]", lo, hi) for i, v in enumerate(items))

    def integers(self, key: str, n: int, lo: int, hi: int) -> tuple[int, ...]:
        items = self._list(key, n)
        return tuple(_check_integer(v, f"{self._name(key)}[{i}]", lo, hi) for i, v in enumerate(items))

    def _list(self, key: str, n: int | None) -> list[Any]:
        value = self._get(key)
        if not isinstance(value, list):
            raise ConfigError(f"{self._name(key)}: expected a list, got {_show(value)}")
        if n is not None and len(value) != n:
            raise ConfigError(f"{self._name(key)}: expected {n} values, got {len(value)}")
        return value

    def finish(self) -> None:
        unknown = sorted(set(self._data) - self._seen)
        if unknown:
            where = self._prefix.rstrip(".") or "the top level"
            known = ", ".join(sorted(self._seen))
            raise ConfigError(f"{self._name(unknown[0])}: unknown key in {where} (known keys: {known})")


def parse_listen(value: object, name: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[IPv6]:PORT`` for an IPv6 address; port 0 takes a free one); ``ConfigError`` naming
    ``name`` otherwise."""
    match = _LISTEN.match(value) if isinstance(value, str) else None
    if match is None or not 0 <= int(match.group(2)) <= 65535:
        raise ConfigError(
            f"{name}: {_show(value)} is not HOST:PORT like 127.0.0.1:8765 (IPv6 as [::1]:8765; port 0-65535)"
        )
    return match.group(1).strip("[]"), int(match.group(2))


def check_foxglove_listen(value: object, name: str, *, insecure: bool) -> tuple[str, int]:
    """A Foxglove server address; a non-loopback one only with ``insecure`` (the server has no
    authentication or encryption: anyone who reaches the port sees everything the robot records)."""
    host, port = parse_listen(value, name)
    if not insecure and not is_loopback(host):
        raise ConfigError(
            f"{name}: {host} is not a loopback address; the Foxglove server has no authentication, so it "
            "listens on 127.0.0.1 unless [foxglove] insecure = true"
        )
    return host, port


def is_loopback(host: str) -> bool:
    """Whether a host name or address is this machine's loopback (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _check_number(value: object, name: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{name}: expected a number in [{lo:g}, {hi:g}], got {_show(value)}")
    if not math.isfinite(value) or not lo <= value <= hi:
        raise ConfigError(f"{name}: {value!r} is out of range; allowed [{lo:g}, {hi:g}]")
    return float(value)


def _check_integer(value: object, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{name}: expected an integer in [{lo}, {hi}], got {_show(value)}")
    if not lo <= value <= hi:
        raise ConfigError(f"{name}: {value} is out of range; allowed [{lo}, {hi}]")
    return value


def _show(value: object) -> str:
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def _merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _plain(value: Any) -> Any:
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if value is None:
        return ""
    return value


def _emit_table(data: Mapping[str, Any], path: list[str], lines: list[str]) -> None:
    scalars = {k: v for k, v in data.items() if not isinstance(v, Mapping)}
    tables = {k: v for k, v in data.items() if isinstance(v, Mapping)}
    if path and scalars:
        lines.append("")
        lines.append(f"[{'.'.join(path)}]")
    for key, value in scalars.items():
        bare = re.fullmatch(r"[A-Za-z0-9_-]+", key) is not None
        lines.append(f"{key if bare else _toml_value(key)} = {_toml_value(value)}")
    for key, value in tables.items():
        _emit_table(value, [*path, key], lines)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")
