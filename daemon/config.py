"""dishbot's configuration: embedded TOML defaults, optional overrides from a file, validated once at load.

Every value is checked when the file is read, so a bad field fails at start-up with its dotted name and the
allowed range (``ConfigError``, exit 2) instead of deep inside a running job. Each section's shape, ranges and
choices are declared once, on the fields of its dataclass (``Annotated[float, within(0.01, 600.0)]``), and
checked by the one validator (``validation.convert``, msgspec underneath) with its one wording; a rule
between fields is the section's own ``__post_init__``. The result is a tree of frozen dataclasses, and the
lower layers' own types where the config describes what they own (``Config.cell`` is the one
``description.cell.CellLayout``, ``Config.mug_types`` the catalogue's ``MugSpec`` entries,
``hardware.fsr`` the FSR reader's ``FsrSettings``, ``hardware.health`` the servo health watch's
``HealthLimits``, ``camera.frames`` the observer's ``FrameLimits``), so they travel to the planners, worlds
and drivers as they are. ``Config.to_dict()`` gives the effective values back in the file's
layout (for ``dishbot config show`` and the recording's session header).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Annotated, Any

from daemon.errors import ConfigError
from daemon.security import ZenohConfig, check_files, check_key, parse_zenoh
from daemon.security import check_endpoint as check_endpoint  # where the verbs have always found it
from description.camera import MAX_FOVY_DEG, MIN_FOVY_DEG, CameraSpec
from description.cell import CellLayout, Tray
from description.errors import InvalidCell
from description.thesis import JOINT_SERVOS, MugSpec, mug_catalogue
from drivers.dynamixel.config import HealthLimits
from drivers.dynamixel.tables import BAUD_CODES_1, BAUD_CODES_2, MODELS
from drivers.fsr.settings import FsrSettings
from perception.frames import FrameAge, FrameLimits, FrameRetries, FrameTimeout
from planning.placement import FOOTPRINTS, METHODS
from recorder.settings import RecordingConfig
from statechart.chart import JOB_LEAVES, JOB_STATES, top_level
from validation import NON_EMPTY, Invalid, OneOf, convert, show, toml, within
from validation.hosts import is_loopback

_ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}\Z")
_BACKENDS = ("sim", "hardware")
_WORLDS = ("kinematic", "mujoco")
_TRANSPORTS = ("inprocess", "pty")
PLANNER_FITNESS = ("rf", "ws")
PLANNER_COSTS = ("bpc", "upc", "ec")
_ENERGY_MODELS = ("thesis", "dynamics")
_CAMERAS = ("realsense", "zenoh", "none")
RECORDING_COMPRESSIONS = ("zstd", "lz4", "none")
_LISTEN = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})\Z")
_MUG_TYPE_NAME = re.compile(r"^[a-z][a-z0-9_]{0,31}\Z")
_MISSING = "missing; add it to the config file"
_DEFAULT_CONFIG = Path(__file__).with_name("default_config.toml")

# Ranges used by more than one field.
Seed = Annotated[int, within(0, 2**31 - 1)]
CellCoordinate = Annotated[float, within(-2.0, 2.0)]
CameraCoordinate = Annotated[float, within(-5.0, 5.0)]
JointAngle = Annotated[float, within(-math.pi, math.pi)]
StateBound = Annotated[float, within(1.0, 3600.0)]
PlannerTimeLimit = Annotated[float, within(0.01, 600.0)]
PlannerMethod = Annotated[str, OneOf(METHODS)]
PlannerFitness = Annotated[str, OneOf(PLANNER_FITNESS)]
PlannerCost = Annotated[str, OneOf(PLANNER_COSTS)]


@dataclass(frozen=True, slots=True)
class FoxgloveConfig:
    """Foxglove's well-known channels in the recordings; the live WebSocket server (``listen = ""``: off)."""

    channels: bool
    listen: str
    insecure: bool
    depth_hz: Annotated[float, within(0.01, 30.0)]

    def __post_init__(self) -> None:
        if self.listen:
            check_foxglove_listen(self.listen, "listen", insecure=self.insecure)

    @property
    def address(self) -> tuple[str, int] | None:
        """The server's host and port, or None when it is off."""
        return parse_listen(self.listen, "foxglove.listen") if self.listen else None


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """The depth camera's calibration file (``dishbot calibrate`` writes it), overriding the pose in
    ``[camera]``, and what a frame must meet (the observer's own ``FrameLimits``: ``frame_timeout_s``,
    ``max_frame_age_s`` and ``frame_retries`` in the file). The camera itself (image size, field of view,
    pose) is part of the cell: ``Config.cell.camera``."""

    calibration_file: Path | None
    frames: FrameLimits = field(default_factory=FrameLimits)


@dataclass(frozen=True, slots=True)
class PlannerConfig:
    """Placement planner settings; a ``start`` command may override method, fitness, cost, time limit and
    seed, checked against these same declarations (``daemon.commands_handler``)."""

    method: PlannerMethod
    fitness: PlannerFitness
    cost: PlannerCost
    time_limit_s: PlannerTimeLimit
    seed: Seed
    tolerance_mm: Annotated[int, within(0, 100)]
    allow_rotation: bool
    energy_model: Annotated[str, OneOf(_ENERGY_MODELS)]
    # "rect" (the thesis's rectangles) or "mug" (brim disc plus handle)
    footprint: Annotated[str, OneOf(FOOTPRINTS)] = "mug"


@dataclass(frozen=True, slots=True)
class DaemonConfig:
    """Telemetry rates and command limits of the daemon process, and how long each job state may last.

    ``state_bounds_s`` maps every top-level job state (``detect``, ``plan``, ...) to the longest it may stay
    entered, and may add bounds of their own for leaves (``"flip.turn"``); a state past its bound faults
    the job (``state detect exceeded its 60 s bound``) instead of stalling it silently, and the systemd
    watchdog is not pinged meanwhile."""

    state_rate_hz: Annotated[float, within(1.0, 100.0)]
    joints_rate_hz: Annotated[float, within(20.0, 500.0)]
    gripper_rate_hz: Annotated[float, within(50.0, 500.0)]
    max_command_bytes: Annotated[int, within(256, 1024 * 1024)]
    drop_check_period_s: Annotated[float, within(0.001, 0.5)]
    state_bounds_s: Mapping[str, float] = field(default_factory=lambda: dict.fromkeys(JOB_STATES, 60.0))

    def state_bound_s(self, state: str) -> float | None:
        """The bound of a job state or leaf (None: it has none of its own)."""
        return self.state_bounds_s.get(state)


@dataclass(frozen=True, slots=True)
class GraspConfig:
    """When a closed gripper counts as holding a mug (§4.3.1: a force threshold and a minimum aperture)."""

    force_threshold_n: Annotated[float, within(0.1, 50.0)]
    min_aperture_m: Annotated[float, within(0.0, 0.2)]
    max_attempts: Annotated[int, within(1, 10)]


@dataclass(frozen=True, slots=True)
class SimConfig:
    """The simulated cell: which world, how it reaches the simulated devices, how fast against the wall
    clock (None: as fast as the machine allows; ``"max"`` in the file), the detector's noise."""

    world: Annotated[str, OneOf(_WORLDS)]
    transport: Annotated[str, OneOf(_TRANSPORTS)]
    speed: Annotated[float, within(0.1, 1000.0)] | None
    seed: Seed
    detection_noise_m: Annotated[float, within(0.0, 0.05)]
    joint_speed_rad_s: Annotated[float, within(0.05, 10.0)]
    start_q_rad: tuple[JointAngle, JointAngle, JointAngle, JointAngle, JointAngle]


@dataclass(frozen=True, slots=True)
class ArmConfig:
    """The arm's position correction (``dishbot calibrate``), applied by the cycle planner, and how it sets
    a held mug down: the last ``set_down_slow_m`` of every set-down (flip and place) at
    ``set_down_speed_m_s``, so that the mug hangs straight when it is let go (0: all at fine speed)."""

    calibration_file: Path | None
    set_down_slow_m: float
    set_down_speed_m_s: float


@dataclass(frozen=True, slots=True)
class ServoConfig:
    """The servo driving one joint (or the gripper): its bus id and model."""

    joint: str
    id: int
    model: str


@dataclass(frozen=True, slots=True)
class HardwareGripperConfig:
    """The real gripper: its angle-to-aperture map (empty: the arm model's geometry) and overload policy."""

    aperture_map: tuple[tuple[JointAngle, Annotated[float, within(0.0, 0.3)]], ...]
    grip_limit: Annotated[float, within(0.05, 1.0)]
    grip_limit_backoff: Annotated[float, within(0.1, 0.95)]
    overload_retries: Annotated[int, within(0, 10)]

    def __post_init__(self) -> None:
        angles = [a for a, _ in self.aperture_map]
        if self.aperture_map and (len(angles) < 2 or angles != sorted(set(angles))):
            raise Invalid(
                "aperture_map: needs at least two [angle, aperture] points in strictly increasing angle "
                "(or [] for the arm model's geometry)"
            )


@dataclass(frozen=True, slots=True)
class ZenohCameraConfig:
    """A depth camera whose node publishes frames on Zenoh (``camera = "zenoh"``, ``daemon.zenoh_camera``):
    the node's endpoint and the key its frames come on."""

    connect: str
    key: str

    def __post_init__(self) -> None:
        check_endpoint(self.connect, "connect")
        check_key(self.key, "key")


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
    fsr: FsrSettings
    camera: str
    camera_serial: str
    zenoh_camera: ZenohCameraConfig
    health: HealthLimits

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
            "frame_timeout_s": self.camera.frames.timeout_s,
            "max_frame_age_s": self.camera.frames.max_age_s,
            "frame_retries": self.camera.frames.retries,
        }
        out["recording"]["compression"] = self.recording.compression or "none"
        out["mug_types"] = {m["name"]: {k: v for k, v in m.items() if k != "name"} for m in out["mug_types"]}
        hw = out["hardware"]
        hw["servos"] = {s["joint"]: {"id": s["id"], "model": s["model"]} for s in hw["servos"]}
        out["sim"]["speed"] = "max" if self.sim.speed is None else self.sim.speed
        if out["zenoh"]["auth"]["password"]:  # shown and recorded everywhere: never the secret itself
            out["zenoh"]["auth"]["password"] = "(hidden)"
        return out


# --- the tables whose layout in the file is not their object's ------------------------------------------


@dataclass(frozen=True, slots=True)
class _Root:
    robot_id: Annotated[str, NON_EMPTY]
    backend: Annotated[str, OneOf(_BACKENDS)]
    zenoh: dict[str, Any]
    recording: dict[str, Any]
    foxglove: dict[str, Any]
    cell: dict[str, Any]
    camera: dict[str, Any]
    mug_types: dict[str, Any]
    planner: dict[str, Any]
    daemon: dict[str, Any]
    grasp: dict[str, Any]
    sim: dict[str, Any]
    arm: dict[str, Any]
    hardware: dict[str, Any]


@dataclass(frozen=True, slots=True)
class _RecordingTable:
    dir: Annotated[str, NON_EMPTY]
    chunk_size_bytes: Annotated[int, within(1024, 16 * 1024 * 1024)]
    compression: Annotated[str, OneOf(RECORDING_COMPRESSIONS)]
    idle_telemetry_hz: Annotated[float, within(0.01, 100.0)]
    idle_file_s: Annotated[float, within(10.0, 7 * 86400.0)]
    job_tail_s: Annotated[float, within(0.0, 60.0)]
    max_total_mb: Annotated[int, within(0, 10**7)]
    max_age_days: Annotated[float, within(0.0, 3650.0)]


@dataclass(frozen=True, slots=True)
class _CellTable:
    counter_region_m: tuple[CellCoordinate, CellCoordinate, CellCoordinate, CellCoordinate]
    flip_area_center_m: tuple[CellCoordinate, CellCoordinate]
    flip_area_radius_m: Annotated[float, within(0.01, 1.0)]
    tray_origin_m: tuple[CellCoordinate, CellCoordinate]
    tray_size_mm: tuple[Annotated[int, within(50, 2000)], Annotated[int, within(50, 2000)]]
    table_height_above_floor_m: Annotated[float, within(0.3, 2.0)]


@dataclass(frozen=True, slots=True)
class _CameraTable:
    width: Annotated[int, within(16, 4096)]
    height: Annotated[int, within(16, 4096)]
    fovy_deg: Annotated[float, within(MIN_FOVY_DEG, MAX_FOVY_DEG)]
    position_m: tuple[CameraCoordinate, CameraCoordinate, CameraCoordinate]
    yaw_rad: Annotated[float, within(-2 * math.pi, 2 * math.pi)]
    pitch_rad: Annotated[float, within(-math.pi / 2, math.pi / 2)]
    calibration_file: str
    frame_timeout_s: FrameTimeout
    max_frame_age_s: FrameAge
    frame_retries: FrameRetries


@dataclass(frozen=True, slots=True)
class _MugTable:
    diameter_mm: Annotated[int, within(20, 300)]
    width_mm: Annotated[int, within(20, 400)]
    height_mm: Annotated[int, within(20, 400)]
    mass_kg: Annotated[float, within(0.01, 2.0)]

    def __post_init__(self) -> None:
        if self.width_mm < self.diameter_mm:
            raise Invalid(
                f"width_mm: {self.width_mm} is smaller than diameter_mm {self.diameter_mm}; the width "
                "includes the handle"
            )


@dataclass(frozen=True, slots=True)
class _ArmTable:
    calibration_file: str
    set_down_slow_m: Annotated[float, within(0.0, 0.1)]
    set_down_speed_m_s: Annotated[float, within(0.002, 0.08)]


@dataclass(frozen=True, slots=True)
class _ServoTable:
    id: Annotated[int, within(0, 252)]
    model: Annotated[str, OneOf(tuple(MODELS))]


@dataclass(frozen=True, slots=True)
class _HardwareTable:
    servo_port: Annotated[str, NON_EMPTY]
    baudrate: int
    protocol: Annotated[int, within(1, 2)]
    retries: Annotated[int, within(0, 10)]
    read_timeout_s: Annotated[float, within(0.001, 1.0)]
    servos: dict[str, Any]
    gripper: HardwareGripperConfig
    fsr: FsrSettings
    camera: Annotated[str, OneOf(_CAMERAS)]
    camera_serial: str
    zenoh_camera: ZenohCameraConfig
    health: HealthLimits


def default_text() -> str:
    """The embedded defaults, comments included."""
    # the package's own file beside this module (importlib.resources would find the same file, at the cost
    # of loading its readers and zipfile: a tenth of the config's load)
    return _DEFAULT_CONFIG.read_text(encoding="utf-8")


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
        data = merge_tables(data, user)
    if overrides:
        data = merge_tables(data, overrides)
    config = parse_config(data)
    if path is not None:
        config = replace(config, zenoh=config.zenoh.resolved(path.parent))
    check_files(config.zenoh)
    return config


def load_cell_and_planner(path: Path | None = None) -> tuple[CellLayout, PlannerConfig]:
    """``load_config(path)``'s cell and planner settings, for a caller that needs no more (``dishbot
    plan``). A file is loaded whole, and so checked whole, by ``load_config``; the embedded defaults alone
    are the same on every run and checked by the tests, so of them only the ``[cell]``, ``[camera]`` and
    ``[planner]`` tables are read, with the same checks: the other sections' checks were two thirds of
    the load's CPU time."""
    if path is not None:
        config = load_config(path)
        return config.cell, config.planner
    root: _Root = _table(tomllib.loads(default_text()), _Root, "")
    planner: PlannerConfig = _table(root.planner, PlannerConfig, "planner")
    camera_spec, _ = _camera(root.camera)
    return _cell(root.cell, camera_spec, tolerance_mm=planner.tolerance_mm), planner


def _table(data: object, kind: type[Any], name: str) -> Any:
    return convert(data, kind, name=name, error=ConfigError, missing=_MISSING)


def parse_config(data: Mapping[str, Any]) -> Config:
    """Validate a complete configuration mapping (all sections present)."""
    root: _Root = _table(data, _Root, "")
    if not _ROBOT_ID.match(root.robot_id):
        raise ConfigError(
            f"robot_id: {root.robot_id!r} is not allowed; use 1-64 letters, digits, '_' or '-' "
            "(a Zenoh key chunk)"
        )
    planner: PlannerConfig = _table(root.planner, PlannerConfig, "planner")
    camera_spec, camera = _camera(root.camera)
    return Config(
        robot_id=root.robot_id,
        backend=root.backend,
        zenoh=parse_zenoh(root.zenoh, "zenoh"),
        recording=_recording(root.recording),
        foxglove=_table(root.foxglove, FoxgloveConfig, "foxglove"),
        cell=_cell(root.cell, camera_spec, tolerance_mm=planner.tolerance_mm),
        camera=camera,
        mug_types=_mug_types(root.mug_types),
        planner=planner,
        daemon=_daemon(root.daemon),
        grasp=_table(root.grasp, GraspConfig, "grasp"),
        sim=_sim(root.sim),
        arm=_arm(_table(root.arm, _ArmTable, "arm")),
        hardware=_hardware(root.hardware),
    )


def _arm(table: _ArmTable) -> ArmConfig:
    return ArmConfig(
        _path_or_none(table.calibration_file),
        set_down_slow_m=table.set_down_slow_m,
        set_down_speed_m_s=table.set_down_speed_m_s,
    )


def to_toml(data: Mapping[str, Any]) -> str:
    """A TOML document for a mapping of the types ``Config.to_dict`` produces (the one TOML writer,
    ``validation.toml``)."""
    return toml.dumps(data)


def _path_or_none(text: str) -> Path | None:
    return Path(text) if text else None


def _recording(data: Mapping[str, Any]) -> RecordingConfig:
    t: _RecordingTable = _table(data, _RecordingTable, "recording")
    return RecordingConfig(
        dir=Path(t.dir),
        chunk_size_bytes=t.chunk_size_bytes,
        compression=None if t.compression == "none" else t.compression,
        idle_telemetry_hz=t.idle_telemetry_hz,
        idle_file_s=t.idle_file_s,
        job_tail_s=t.job_tail_s,
        max_total_mb=t.max_total_mb,
        max_age_days=t.max_age_days,
    )


def _cell(data: Mapping[str, Any], camera: CameraSpec, *, tolerance_mm: int) -> CellLayout:
    """``[cell]`` with the camera of ``[camera]``: the one cell layout (its own checks name the field)."""
    t: _CellTable = _table(data, _CellTable, "cell")
    try:
        return CellLayout(
            counter_region_m=t.counter_region_m,
            flip_area_center_m=t.flip_area_center_m,
            flip_area_radius_m=t.flip_area_radius_m,
            tray=Tray(origin_m=t.tray_origin_m, size_mm=t.tray_size_mm),
            camera=camera,
            table_height_above_floor_m=t.table_height_above_floor_m,
            tolerance_mm=tolerance_mm,
        )
    except InvalidCell as e:
        raise ConfigError(str(e)) from e


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


def _camera(data: Mapping[str, Any]) -> tuple[CameraSpec, CameraConfig]:
    t: _CameraTable = _table(data, _CameraTable, "camera")
    try:
        spec = CameraSpec(
            width=t.width,
            height=t.height,
            fovy_deg=t.fovy_deg,
            position_m=t.position_m,
            yaw_rad=t.yaw_rad,
            pitch_rad=t.pitch_rad,
        )
    except InvalidCell as e:
        raise ConfigError(str(e)) from e
    camera = CameraConfig(
        calibration_file=_path_or_none(t.calibration_file),
        frames=FrameLimits(t.frame_timeout_s, t.max_frame_age_s, t.frame_retries),
    )
    return spec, camera


def _mug_types(data: Mapping[str, Any]) -> tuple[MugSpec, ...]:
    mugs = []
    for name, table in data.items():
        if not _MUG_TYPE_NAME.match(name):
            raise ConfigError(f"mug_types.{name}: mug type names are 1-32 lower-case letters, digits or '_'")
        t: _MugTable = _table(table, _MugTable, f"mug_types.{name}")
        mugs.append(MugSpec(name, t.diameter_mm, t.width_mm, t.height_mm, t.mass_kg))
    if not mugs:
        raise ConfigError("mug_types: the catalogue is empty; define at least one [mug_types.NAME] table")
    return tuple(mugs)


def _daemon(data: Mapping[str, Any]) -> DaemonConfig:
    bounds = data.get("state_bounds_s")
    checked = {**data, "state_bounds_s": _state_bounds(bounds) if isinstance(bounds, Mapping) else bounds}
    cfg: DaemonConfig = _table(checked, DaemonConfig, "daemon")
    return cfg


def _state_bounds(data: Mapping[str, Any]) -> dict[str, float]:
    """``[daemon.state_bounds_s]``: a bound for every top-level job state, optionally for leaves too."""
    where = "daemon.state_bounds_s"
    bounds = {}
    for name, value in data.items():
        if name not in JOB_STATES and name not in JOB_LEAVES:
            raise ConfigError(
                f"{where}.{name}: {name!r} is not a job state or leaf (states: {', '.join(JOB_STATES)}; "
                'leaves such as "flip.turn")'
            )
        bounds[name] = _table(value, StateBound, f"{where}.{name}")
    missing = [state for state in JOB_STATES if state not in bounds]
    if missing:
        raise ConfigError(f"{where}.{missing[0]}: missing; every job state needs a bound")
    for leaf, bound in bounds.items():
        state = top_level(leaf)
        if leaf != state and bound > bounds[state]:
            raise ConfigError(
                f"{where}.{leaf}: {bound:g} s is longer than {state}'s own bound of {bounds[state]:g} s"
            )
    return bounds


def _sim(data: Mapping[str, Any]) -> SimConfig:
    speed = data.get("speed")
    if isinstance(speed, str):
        if speed != "max":
            raise ConfigError(f'sim.speed: expected "max" or a number in [0.1, 1000], got {speed!r}')
        data = {**data, "speed": None}
    elif speed is None and "speed" in data:
        raise ConfigError('sim.speed: expected "max" or a number in [0.1, 1000], got None')
    cfg: SimConfig = _table(data, SimConfig, "sim")
    return cfg


def _hardware(data: Mapping[str, Any]) -> HardwareConfig:
    t: _HardwareTable = _table(data, _HardwareTable, "hardware")
    rates = BAUD_CODES_1 if t.protocol == 1 else BAUD_CODES_2
    if t.baudrate not in rates:
        allowed = ", ".join(str(r) for r in sorted(rates))
        raise ConfigError(
            f"hardware.baudrate: {show(t.baudrate)} is not a Protocol {t.protocol}.0 rate; use {allowed}"
        )
    return HardwareConfig(
        servo_port=t.servo_port,
        baudrate=t.baudrate,
        protocol=t.protocol,
        retries=t.retries,
        read_timeout_s=t.read_timeout_s,
        servos=_servos(t.servos, t.protocol),
        gripper=t.gripper,
        fsr=t.fsr,
        camera=t.camera,
        camera_serial=t.camera_serial,
        zenoh_camera=t.zenoh_camera,
        health=t.health,
    )


def _servos(data: Mapping[str, Any], protocol: int) -> tuple[ServoConfig, ...]:
    where = "hardware.servos"
    joints = [joint for joint, _ in JOINT_SERVOS]
    for joint in data:
        if joint not in joints:
            raise ConfigError(
                f"{where}.{joint}: unknown key in {where} (known keys: {', '.join(sorted(joints))})"
            )
    servos = []
    for joint in joints:
        if joint not in data:
            raise ConfigError(f"{where}.{joint}: {_MISSING}")
        t: _ServoTable = _table(data[joint], _ServoTable, f"{where}.{joint}")
        if MODELS[t.model].protocol != protocol:
            raise ConfigError(
                f"{where}.{joint}.model: {t.model} speaks Protocol {MODELS[t.model].protocol}.0 but "
                f"hardware.protocol is {protocol}"
            )
        servos.append(ServoConfig(joint, t.id, t.model))
    seen: dict[int, str] = {}
    for servo in servos:
        if servo.id in seen:
            raise ConfigError(
                f"{where}.{servo.joint}.id: {servo.id} is already the id of {seen[servo.id]}; "
                "every servo on the bus needs its own id"
            )
        seen[servo.id] = servo.joint
    return tuple(servos)


def parse_listen(value: object, name: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[IPv6]:PORT`` for an IPv6 address; port 0 takes a free one); ``ConfigError`` naming
    ``name`` otherwise."""
    match = _LISTEN.match(value) if isinstance(value, str) else None
    if match is None or not 0 <= int(match.group(2)) <= 65535:
        raise ConfigError(
            f"{name}: {show(value)} is not HOST:PORT like 127.0.0.1:8765 (IPv6 as [::1]:8765; port 0-65535)"
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


def merge_tables(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``update`` laid over it table by table (a nested table keeps the keys ``update`` does
    not name), as a config file and overrides are laid over the defaults."""
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge_tables(out[key], value)
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
