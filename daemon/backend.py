"""What a loading job runs on: the devices, the observer and the motion planner, bundled as a ``Backend``.

The job runner only sees the protocols of ``drivers.interfaces``, ``perception.interfaces`` and
``planning.interfaces``. ``open_backend`` builds the bundle the configuration asks for; ``recorded`` wraps one
so that every input crossing the driver boundary (joint feedback, force readings, grasp results, observations)
is also handed to the recording, which is what a replay needs.
"""

from __future__ import annotations

import base64
import concurrent.futures
import contextlib
import dataclasses
import functools
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
import structlog

from daemon.clock import RealClock, SessionClock
from daemon.config import CellConfig, Config, MugTypeConfig
from daemon.errors import UsageError
from description import thesis
from description.thesis import MugSpec
from drivers.dynamixel import BusConfig, DeviceEvent
from drivers.errors import BusLost, DriverError
from drivers.interfaces import (
    ArmDriver,
    Camera,
    ForceReading,
    ForceSensor,
    GraspResult,
    GripperDriver,
    GripperState,
    JointState,
    JointTrajectory,
)
from drivers.stack import (
    ARM_JOINTS,
    DeviceStack,
    FsrSettings,
    StackSpec,
    arm_joints,
    gripper_spec,
    open_device_stack,
)
from perception.interfaces import Detection, MugObserver, Observation
from planning.arm import ArmModel
from planning.arm.calibration import PositionCorrection
from planning.arm.grasp import handle_facing_away_rad
from planning.interfaces import CyclePlan, MotionPlanner, MugPose, TraySlot
from planning.motion import CellLayout, DynamicsMoveCost
from planning.motion.planner import CyclePlanner
from planning.placement import PlanOptions, PlanResult, Problem, dataset_problem, plan
from sim.kinematic import MugGeometry, SimMug, open_kinematic_cell
from sim.truth import TruthObserver

log = structlog.get_logger("daemon.backend")


@dataclass(frozen=True, slots=True)
class Tray:
    """The tray in the world frame: the corner nearest the arm base, and its extent in mm (as planned)."""

    origin_m: tuple[float, float]
    size_mm: tuple[int, int]

    def contains(self, x_m: float, y_m: float) -> bool:
        """Whether a point of the world frame lies over the tray."""
        x0, y0 = self.origin_m
        return x0 <= x_m <= x0 + self.size_mm[0] / 1000.0 and y0 <= y_m <= y0 + self.size_mm[1] / 1000.0


@dataclass(frozen=True, slots=True)
class CounterMug:
    """A mug a simulated counter is set up with (``start`` body ``mugs``)."""

    mug_id: str
    type: str
    x_m: float
    y_m: float


class CounterSetup(Protocol):
    """Only a simulated cell can put mugs on its counter; it returns the tray the job should fill."""

    def set_counter(self, *, dataset: int | None, mugs: Sequence[CounterMug] | None) -> Tray: ...

    def scene(self) -> dict[str, object]: ...


EventListener = Callable[[Mapping[str, object]], None]


def device_event_payload(event: DeviceEvent, *, t: float) -> dict[str, object]:
    """A driver's fault or recovery as published on ``events``: ``kind`` (``servo_fault``, ``bus_lost``,
    ``fsr_stale``, ...), ``device`` and its detail; ``t`` the clock's ``now()``, ``t_device`` the driver's
    clock."""
    detail = {
        k: v if isinstance(v, str | int | float | bool) or v is None else str(v)
        for k, v in event.detail.items()
    }
    return {**detail, "kind": event.kind, "device": event.device, "t": t, "t_device": event.t}


class _DeviceEvents:
    """Fans driver events out to the listeners registered through ``Backend.on_event``."""

    def __init__(self, clock: SessionClock) -> None:
        self._clock = clock
        self._listeners: list[EventListener] = []

    def add(self, listener: EventListener) -> None:
        self._listeners.append(listener)

    def __call__(self, event: DeviceEvent) -> None:
        payload = device_event_payload(event, t=self._clock.now())
        for listener in self._listeners:
            listener(payload)


async def _nothing() -> None:
    return None


@dataclass(slots=True)
class Backend:
    """The bundle a job runs on. ``tray`` may change when a simulated counter is set up for a new job."""

    name: str
    arm: ArmDriver
    gripper: GripperDriver
    force: ForceSensor
    observer: MugObserver
    motion: MotionPlanner
    tray: Tray
    counter: CounterSetup | None = None
    closer: Callable[[], Awaitable[None]] = field(default=_nothing)
    # The motion planner for another tray (a simulated counter set up with a different tray).
    motion_for: Callable[[Tray], MotionPlanner] | None = None
    # Devices that report events of their own (tray collisions in simulation) call the listener given here,
    # possibly from another thread.
    on_event: Callable[[EventListener], None] | None = None
    # The Dynamixel/FSR device stack when the backend runs one (hardware): bus counters, diagnostics.
    devices: DeviceStack | None = None
    # The one clock everything of this backend and the job on it reads and waits on: the wall clock on the
    # robot, the simulated cell's clock in simulation.
    clock: SessionClock = field(default_factory=RealClock)

    def scene(self) -> dict[str, object]:
        """The initial scene for the recording's session header."""
        base: dict[str, object] = {
            "backend": self.name,
            "tray": {"origin_m": list(self.tray.origin_m), "size_mm": list(self.tray.size_mm)},
        }
        if self.counter is not None:
            base.update(self.counter.scene())
        return base

    async def close(self) -> None:
        await self.closer()


Sink = Callable[[str, Mapping[str, object]], None]


def recorded(backend: Backend, sink: Sink) -> Backend:
    """The same backend, with driver-boundary inputs also passed to ``sink(kind, payload)``."""
    clock = backend.clock
    return replace(
        backend,
        arm=_RecordedArm(backend.arm, sink, clock),
        gripper=_RecordedGripper(backend.gripper, sink),
        force=_RecordedForce(backend.force, sink, clock),
        observer=_RecordedObserver(backend.observer, sink, clock),
    )


def joints_payload(js: JointState, *, t: float) -> dict[str, object]:
    """``t`` is the clock's ``now()`` when published, ``t_device`` the driver's (monotonic) time."""
    return {
        "t": t,
        "t_device": js.t,
        "names": list(js.names),
        "position_rad": [round(v, 6) for v in js.position_rad],
        "velocity_rad_s": [round(v, 6) for v in js.velocity_rad_s],
        "load": [round(v, 4) for v in js.load],
    }


def observation_payload(obs: Observation, *, t: float) -> dict[str, object]:
    """``t`` is the clock's ``now()`` when published, ``t_device`` the observation's (monotonic) time."""
    return {"t": t, "t_device": obs.t, "mugs": [d.to_json() for d in obs.detections], "meta": dict(obs.meta)}


def depth_preview_payload(depth_m: npt.NDArray[np.float32]) -> dict[str, object]:
    """A small depth image for monitors: unsigned 16-bit millimetres (0 = no reading), little-endian,
    row-major, base64."""
    mm = np.nan_to_num(np.asarray(depth_m, dtype=np.float64) * 1000.0, nan=0.0, posinf=0.0, neginf=0.0)
    data = np.clip(np.rint(mm), 0, 65535).astype("<u2")
    return {
        "width": int(data.shape[1]),
        "height": int(data.shape[0]),
        "encoding": "uint16_mm_le_base64",
        "data": base64.b64encode(data.tobytes()).decode("ascii"),
    }


class _RecordedArm:
    def __init__(self, inner: ArmDriver, sink: Sink, clock: SessionClock) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._inner.joint_names

    async def read_joints(self) -> JointState:
        js = await self._inner.read_joints()
        self._sink("input/joints", joints_payload(js, t=self._clock.now()))
        return js

    async def follow(self, trajectory: JointTrajectory) -> None:
        await self._inner.follow(trajectory)

    async def stop(self) -> None:
        await self._inner.stop()

    async def relax(self) -> None:
        await self._inner.relax()


class _RecordedGripper:
    def __init__(self, inner: GripperDriver, sink: Sink) -> None:
        self._inner = inner
        self._sink = sink

    async def read(self) -> GripperState:
        return await self._inner.read()

    async def open(self, aperture_m: float | None = None) -> None:
        await self._inner.open(aperture_m)

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        result = await self._inner.close_on_mug(
            force_threshold_n=force_threshold_n, min_aperture_m=min_aperture_m
        )
        self._sink(
            "input/grasp",
            {
                "held": result.held,
                "force_n": result.force_n,
                "aperture_m": result.aperture_m,
                "reason": result.reason,
            },
        )
        return result

    async def stop(self) -> None:
        await self._inner.stop()


class _RecordedForce:
    def __init__(self, inner: ForceSensor, sink: Sink, clock: SessionClock) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock

    def latest(self) -> ForceReading | None:
        reading = self._inner.latest()
        if reading is not None:
            self._sink(
                "input/force",
                {
                    "t": self._clock.now(),
                    "t_device": reading.t,
                    "force_n": reading.force_n,
                    "raw": reading.raw,
                    "seq": reading.seq,
                },
            )
        return reading

    def holding(self) -> bool:
        held = self._inner.holding()
        self._sink("input/holding", {"holding": held})
        return held


class _RecordedObserver:
    def __init__(self, inner: MugObserver, sink: Sink, clock: SessionClock) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock

    async def observe(self) -> Observation:
        obs = await self._inner.observe()
        self._sink("input/observation", observation_payload(obs, t=self._clock.now()))
        return obs


async def open_sim_backend(
    config: Config,
    *,
    world: str,
    dataset: int,
    clock: SessionClock,
    seed: int,
    transport: str = "inprocess",
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The simulated cell with dataset ``dataset``'s mugs on its counter, on ``clock``: ``kinematic`` (the
    placeholder cell) or ``mujoco`` (the physics simulation; ``transport`` ``"inprocess"`` on a simulated
    clock, ``"pty"`` on the wall clock). With ``executor`` (a process pool), motion planning runs there.
    Call it on the event loop that will use the devices (the clock's)."""
    if world == "mujoco":
        return await open_mujoco_backend(
            config, dataset=dataset, seed=seed, clock=clock, transport=transport, executor=executor
        )
    if world != "kinematic":
        raise UsageError(f"--world {world}: choose kinematic or mujoco")
    return open_kinematic_backend(config, dataset=dataset, clock=clock, seed=seed, executor=executor)


def open_kinematic_backend(
    config: Config,
    *,
    dataset: int,
    clock: SessionClock,
    seed: int,
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The kinematic placeholder cell (``sim.kinematic``), moving on ``clock``."""
    arm_model = ArmModel.load()
    counter = _KinematicCounter(config, arm_model, clock=clock)
    tray = counter.set_counter(dataset=dataset, mugs=None)
    cell = counter.cell
    observer = TruthObserver(
        counter.visible_mugs, clock=clock, noise_m=config.sim.detection_noise_m, seed=seed
    )
    correction = load_correction(config)

    def motion_for(tray: Tray) -> MotionPlanner:
        spec = CyclePlannerSpec(config.cell, tray, config.mug_types, correction)
        return spec.build(arm_model) if executor is None else ProcessMotionPlanner(spec, executor)

    return Backend(
        name="sim-kinematic",
        arm=cell.arm,
        gripper=cell.gripper,
        force=cell.force,
        observer=observer,
        motion=motion_for(tray),
        tray=tray,
        counter=counter,
        motion_for=motion_for,
        clock=clock,
    )


class _KinematicCounter:
    """Sets the kinematic cell's counter up for a job: a placement dataset or an explicit list of mugs."""

    def __init__(self, config: Config, arm: ArmModel, *, clock: SessionClock) -> None:
        self._config = config
        self._arm = arm
        self._geometry = {
            m.name: MugGeometry(m.diameter_mm / 1000.0, m.height_mm / 1000.0) for m in config.mug_types
        }
        self.tray = Tray(config.cell.tray_origin_m, config.cell.tray_size_mm)
        self.cell = open_kinematic_cell(
            [],
            self._geometry,
            tray_origin_m=self.tray.origin_m,
            tray_size_m=(self.tray.size_mm[0] / 1000.0, self.tray.size_mm[1] / 1000.0),
            clock=clock,
            joint_speed_rad_s=config.sim.joint_speed_rad_s,
            holding_threshold_n=config.grasp.force_threshold_n / 2.0,
            arm=arm,
            q0=np.asarray(config.sim.start_q_rad, dtype=np.float64),
        )
        self.dataset: int | None = None

    def set_counter(self, *, dataset: int | None, mugs: Sequence[CounterMug] | None) -> Tray:
        if mugs is not None:
            sim_mugs = [
                SimMug(m.mug_id, m.type, m.x_m, m.y_m, handle_yaw_rad=handle_facing_away_rad(m.x_m, m.y_m))
                for m in mugs
            ]
            tray = Tray(self._config.cell.tray_origin_m, self._config.cell.tray_size_mm)
        else:
            problem = self._dataset(dataset or 1)
            sim_mugs = [
                SimMug(m.id, m.type, x, y, handle_yaw_rad=handle_facing_away_rad(x, y))
                for m in problem.mugs
                for x, y in [(m.x_mm / 1000.0, m.y_mm / 1000.0)]
            ]
            origin = (problem.tray_origin_mm[0] / 1000.0, problem.tray_origin_mm[1] / 1000.0)
            tray = Tray(origin, problem.tray_size_mm)
        unknown = sorted({m.type for m in sim_mugs} - set(self._geometry))
        if unknown:
            raise ValueError(f"mug types {', '.join(unknown)} are not in the configured catalogue")
        self.dataset = dataset if mugs is None else None
        world = self.cell.world
        world.set_mugs(sim_mugs)
        world.tray_origin_m = tray.origin_m
        world.tray_size_m = (tray.size_mm[0] / 1000.0, tray.size_mm[1] / 1000.0)
        self.tray = tray
        return tray

    def _dataset(self, n: int) -> Problem:
        ds = thesis.DATASETS[n]
        robot_tray = ds.tray_mm == thesis.ROBOT_TRAY_MM
        return dataset_problem(
            n,
            counter_region_m=self._config.cell.counter_region_m,
            tray_origin_m=self._config.cell.tray_origin_m if robot_tray else None,
        )

    def visible_mugs(self) -> list[Detection]:
        return [
            Detection(m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, 1.0)
            for m in self.cell.world.mugs.values()
            if m.where == "counter"
        ]

    def scene(self) -> dict[str, object]:
        return {**self.cell.world.scene(), "dataset": self.dataset}


@runtime_checkable
class SlotPlanner(Protocol):
    """A motion planner that can fill a tray slot with another counter mug of the same type when the one the
    slot names cannot be reached (``CyclePlanner.plan_for_slot``)."""

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]: ...


def catalogue_of(config: Config) -> dict[str, MugSpec]:
    """The configured mug catalogue as the planners take it."""
    return {
        m.name: MugSpec(m.name, m.diameter_mm, m.width_mm, m.height_mm, m.mass_kg) for m in config.mug_types
    }


def load_correction(config: Config) -> PositionCorrection | None:
    """The arm's position correction named by ``arm.calibration_file``; a bad file is a usage error."""
    path = config.arm.calibration_file
    if path is None:
        return None
    try:
        return PositionCorrection.load(path)
    except ValueError as e:  # CalibrationError
        raise UsageError(f"arm.calibration_file: {e}") from e


def check_cell_reachable(config: Config, arm: ArmModel) -> None:
    """Refuse a configured cell the arm cannot serve: every counter, flip-area and tray corner must be
    reachable with every mug type of the catalogue (``CellLayout.check_reachable``)."""
    problems = CellLayout.from_config(config.cell).check_reachable(arm, catalogue_of(config))
    if problems:
        raise UsageError(f"the arm cannot serve the configured cell: {'; '.join(problems)}")


@dataclass(frozen=True, slots=True)
class CyclePlannerSpec:
    """Everything needed to build the cycle planner, hashable and picklable, so that a planning process can
    build it once and reuse it. ``correction`` is the arm's position correction (``arm.calibration_file``)."""

    cell: CellConfig
    tray: Tray
    mug_types: tuple[MugTypeConfig, ...]
    correction: PositionCorrection | None = None

    def layout(self) -> CellLayout:
        layout = CellLayout.from_config(self.cell)
        return dataclasses.replace(layout, tray_origin_m=self.tray.origin_m, tray_size_mm=self.tray.size_mm)

    def catalogue(self) -> dict[str, MugSpec]:
        return {
            m.name: MugSpec(m.name, m.diameter_mm, m.width_mm, m.height_mm, m.mass_kg) for m in self.mug_types
        }

    def build(self, arm: ArmModel | None = None) -> CyclePlanner:
        return CyclePlanner(
            arm or ArmModel.load(), self.layout(), self.catalogue(), correction=self.correction
        )

    def move_cost(self) -> DynamicsMoveCost:
        """The placement move cost from the arm's dynamics (``planner.energy_model = "dynamics"``)."""
        return DynamicsMoveCost(ArmModel.load(), self.layout(), self.catalogue())


@functools.lru_cache(maxsize=4)
def _planner_in_this_process(spec: CyclePlannerSpec) -> CyclePlanner:
    return spec.build()


@functools.lru_cache(maxsize=4)
def _move_cost_in_this_process(spec: CyclePlannerSpec) -> DynamicsMoveCost:
    return spec.move_cost()


def plan_placement(problem: Problem, options: PlanOptions, dynamics: CyclePlannerSpec | None) -> PlanResult:
    """Placement planning; with ``dynamics``, move costs come from the arm's dynamics in that cell (built once
    per process: it plans reference cycles). Module-level, so a process pool can run it."""
    if dynamics is not None:
        options = dataclasses.replace(options, move_cost=_move_cost_in_this_process(dynamics))
    return plan(problem, options)


def _build_in_this_process(spec: CyclePlannerSpec) -> None:
    _planner_in_this_process(spec)


def _plan_cycle(
    spec: CyclePlannerSpec,
    start_q: tuple[float, ...],
    mug: MugPose,
    slot: TraySlot,
    on_tray: tuple[TraySlot, ...],
    counter: tuple[MugPose, ...],
) -> CyclePlan:
    return _planner_in_this_process(spec).plan_cycle(start_q, mug, slot, on_tray, counter=counter)


def _plan_for_slot(
    spec: CyclePlannerSpec,
    start_q: tuple[float, ...],
    slot: TraySlot,
    counter: tuple[MugPose, ...],
    on_tray: tuple[TraySlot, ...],
) -> tuple[MugPose, CyclePlan]:
    return _planner_in_this_process(spec).plan_for_slot(start_q, slot, counter, on_tray)


def _plan_move(
    spec: CyclePlannerSpec, start_q: tuple[float, ...], goal_q: tuple[float, ...], label: str
) -> JointTrajectory:
    return _planner_in_this_process(spec).plan_move(start_q, goal_q, label=label)


class ProcessMotionPlanner:
    """A ``MotionPlanner`` whose planning runs in another process (``executor``, a process pool).

    Planning is CPU-bound Python and C++ that holds the GIL; in the daemon's process it would stall the event
    loop (telemetry, commands) for tens of milliseconds at a time. Calls block until the result is back, so
    the job calls them from a thread (``asyncio.to_thread``), as it does any planner."""

    def __init__(self, spec: CyclePlannerSpec, executor: concurrent.futures.Executor) -> None:
        self._spec = spec
        self._executor = executor

    def warm_up(self) -> concurrent.futures.Future[None]:
        """Build the planner in the worker now (model loading takes a while), not on the first mug."""
        return self._executor.submit(_build_in_this_process, self._spec)

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        future = self._executor.submit(
            _plan_cycle, self._spec, tuple(start_q), mug, slot, tuple(on_tray), tuple(counter)
        )
        return future.result()

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        future = self._executor.submit(
            _plan_for_slot, self._spec, tuple(start_q), slot, tuple(counter), tuple(on_tray)
        )
        return future.result()

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        return self._executor.submit(_plan_move, self._spec, tuple(start_q), tuple(goal_q), label).result()


async def open_mujoco_backend(
    config: Config,
    *,
    dataset: int,
    seed: int,
    clock: SessionClock,
    transport: str = "inprocess",
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The MuJoCo cell (``sim.mujoco``): real drivers over simulated servos and FSR, a rendered depth
    camera and the depth detector; dataset ``dataset``'s mugs on the counter. In-process on a simulated
    ``clock`` it runs as fast as the machine allows (or at the clock's speed); on pseudo-terminals it runs
    on the wall clock. Call it on the event loop that will use the devices (the clock's)."""
    from description.cell import SceneLayout
    from sim.mujoco.cell import scene_mugs, start_sim_cell

    plain = config.to_dict()
    try:
        layout = SceneLayout.from_config(plain["cell"], plain["camera"])
    except ValueError as e:
        raise UsageError(f"the MuJoCo cell cannot use this config: {e}") from e
    catalogue = catalogue_of(config)
    tray = Tray(config.cell.tray_origin_m, config.cell.tray_size_mm)

    def entries(
        dataset: int | None, mugs: Sequence[CounterMug] | None
    ) -> list[tuple[str, str, float, float]]:
        if mugs is not None:
            return [(m.mug_id, m.type, m.x_m, m.y_m) for m in mugs]
        problem = dataset_problem(
            dataset or 1, counter_region_m=config.cell.counter_region_m, tray_origin_m=tray.origin_m
        )
        return [(m.id, m.type, m.x_mm / 1000.0, m.y_mm / 1000.0) for m in problem.mugs]

    try:
        cell, closer = await start_sim_cell(
            layout,
            scene_mugs(entries(dataset, None), catalogue),
            clock=clock,
            transport=transport,
            seed=seed,
            holding_threshold_n=config.grasp.force_threshold_n / 2.0,
        )
    except ValueError as e:  # a transport the clock cannot drive
        raise UsageError(str(e)) from e

    class _Counter:
        def __init__(self) -> None:
            self.dataset: int | None = dataset

        def set_counter(self, *, dataset: int | None, mugs: Sequence[CounterMug] | None) -> Tray:
            cell.set_counter(scene_mugs(entries(dataset, mugs), catalogue))
            self.dataset = dataset if mugs is None else None
            return tray

        def scene(self) -> dict[str, object]:
            return {**cell.scene(), "dataset": self.dataset}

    spec = CyclePlannerSpec(config.cell, tray, config.mug_types, load_correction(config))
    motion: MotionPlanner = spec.build() if executor is None else ProcessMotionPlanner(spec, executor)

    def on_event(listener: EventListener) -> None:
        cell.on_collision(
            lambda c: listener({**c.to_event(), "kind": "tray_collision", "t_sim": c.t, "t": clock.now()})
        )
        cell.on_device_event(lambda e: listener(device_event_payload(e, t=clock.now())))

    return Backend(
        name="sim-mujoco",
        arm=cell.arm,
        gripper=cell.gripper,
        force=cell.force,
        observer=cell.observer,
        motion=motion,
        tray=tray,
        counter=_Counter(),
        closer=closer,
        on_event=on_event,
        clock=clock,
    )


def hardware_stack_spec(config: Config, arm: ArmModel) -> StackSpec:
    """The device stack of ``[hardware]``: each joint's servo with the URDF's limits, the gripper (its
    measured aperture map, or the arm model's gripper geometry when none is given), the FSR and the bus."""
    hw = config.hardware
    try:
        joints = arm_joints([(j, hw.servo(j).id, hw.servo(j).model) for j in ARM_JOINTS])
        grip = hw.servo("gripper")
        gripper = dataclasses.replace(
            gripper_spec(arm.gripper, servo_id=grip.id),
            model=grip.model,
            grip_limit=hw.gripper.grip_limit,
            grip_limit_backoff=hw.gripper.grip_limit_backoff,
            overload_retries=hw.gripper.overload_retries,
        )
        if hw.gripper.aperture_map:
            apertures = [m for _, m in hw.gripper.aperture_map]
            gripper = dataclasses.replace(
                gripper, aperture_map=hw.gripper.aperture_map, open_aperture_m=max(apertures)
            )
        fsr = hw.fsr
        return StackSpec(
            bus=BusConfig(hw.servo_port, hw.baudrate, 1 if hw.protocol == 1 else 2),
            joints=joints,
            gripper=gripper,
            fsr=FsrSettings(
                fsr.port,
                threshold_n=fsr.threshold_n,
                release_n=fsr.release_n,
                gain=fsr.gain,
                debounce_s=fsr.debounce_s,
                stale_after_s=fsr.stale_after_s,
            ),
            retries=hw.retries,
            read_timeout_s=hw.read_timeout_s,
        )
    except ValueError as e:
        raise UsageError(f"hardware: {e}") from e


class _NoCamera:
    """``hardware.camera = "none"``: the devices run (telemetry, faults, commands) but the counter looks
    empty, so a started job ends done at once."""

    def __init__(self, clock: SessionClock) -> None:
        self._clock = clock

    async def observe(self) -> Observation:
        return Observation(t=self._clock.monotonic(), detections=(), meta={"source": "none"})


async def open_hardware_backend(
    config: Config,
    *,
    executor: concurrent.futures.Executor | None = None,
    camera: Camera | None = None,
    clock: SessionClock | None = None,
) -> Backend:
    """The robot: the device stack of ``[hardware]`` on its serial ports (the same stack the MuJoCo cell
    builds over its simulators) and the RealSense camera with the depth detector, on the wall clock
    (``clock``, default a ``RealClock``). ``camera`` replaces the configured camera (a stand-in for tests).
    A missing port, a missing pyrealsense2 or a servo chain that does not match the config is a one-line
    ``UsageError``. Call it on the event loop that will use the devices."""
    clock = clock or RealClock()
    hw = config.hardware
    for key, port in (("hardware.servo_port", hw.servo_port), ("hardware.fsr.port", hw.fsr.port)):
        if not Path(port).exists():  # noqa: ASYNC240 (one stat at start-up, before any device runs)
            raise UsageError(
                f"{key}: {port} does not exist; plug the adapter in and install the udev rule "
                "(docs/hardware.md), or set the port"
            )
    if camera is None and hw.camera == "realsense":
        from drivers.camera import CameraUnavailable, load_pyrealsense

        try:
            load_pyrealsense()
        except CameraUnavailable as e:
            raise UsageError(f"hardware.camera: {e}") from e
    arm_model = ArmModel.load()
    spec = hardware_stack_spec(config, arm_model)
    correction = load_correction(config)
    events = _DeviceEvents(clock)
    stack = contextlib.AsyncExitStack()
    try:
        devices = await open_device_stack(spec, stack, clock=clock, on_event=events)
        observer = await _hardware_observer(config, stack, camera, clock)
    except BaseException as e:
        await stack.aclose()
        if isinstance(e, DriverError | BusLost):
            raise UsageError(f"cannot open the robot's devices: {e}") from e
        raise
    tray = Tray(config.cell.tray_origin_m, config.cell.tray_size_mm)
    planner_spec = CyclePlannerSpec(config.cell, tray, config.mug_types, correction)

    async def close() -> None:
        """Torque off and close the ports; a device that is already gone (unplugged, faulted) cannot be
        switched off and is only logged, so the daemon still exits cleanly."""
        try:
            await stack.aclose()
        except (DriverError, BusLost) as e:
            log.warning("device_close_failed", error=str(e))

    motion: MotionPlanner = (
        planner_spec.build(arm_model) if executor is None else ProcessMotionPlanner(planner_spec, executor)
    )
    return Backend(
        name="hardware",
        arm=devices.arm,
        gripper=devices.gripper,
        force=devices.force,
        observer=observer,
        motion=motion,
        tray=tray,
        closer=close,
        on_event=events.add,
        devices=devices,
        clock=clock,
    )


async def _hardware_observer(
    config: Config, stack: contextlib.AsyncExitStack, camera: Camera | None, clock: SessionClock
) -> MugObserver:
    """The mug observer on the configured camera: depth detection over the table, the tray left out."""
    from description.cell import SceneLayout
    from drivers.camera import RealSenseCamera
    from perception.calibration import camera_model
    from perception.observer import cell_observer_factory

    if camera is None and config.hardware.camera == "none":
        return _NoCamera(clock)
    plain = config.to_dict()
    c = config.camera
    try:
        layout = SceneLayout.from_config(plain["cell"], plain["camera"])
        model = camera_model(
            width=c.width,
            height=c.height,
            fovy_deg=c.fovy_deg,
            position_m=c.position_m,
            yaw_rad=c.yaw_rad,
            pitch_rad=c.pitch_rad,
            calibration_file=c.calibration_file,
        )
    except ValueError as e:
        raise UsageError(f"camera: {e}") from e
    if camera is None:
        camera = await stack.enter_async_context(
            RealSenseCamera(
                world_from_camera=model.world_from_camera,
                width=c.width,
                height=c.height,
                serial_number=config.hardware.camera_serial or None,
                clock=clock,
            )
        )
    return cell_observer_factory(layout, catalogue_of(config))(camera)
