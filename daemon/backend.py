"""What a loading job runs on: the devices, the observer and the motion planner, bundled as a ``Backend``.

The job runner only sees the protocols of ``drivers.interfaces``, ``perception.interfaces`` and
``planning.interfaces``. ``daemon.cell.open_backend`` is the one builder: ``dishbot run`` and every bench get
their cell from it, the robot (assembled here) or a simulated cell (``daemon.sim_backend``, imported only for
one, so the hardware backend loads neither the simulated worlds nor MuJoCo). ``recorded`` wraps a backend so
that every input crossing the driver boundary (joint feedback, force readings, grasp results, observations) is
also handed to the recording, which is what a replay needs.
"""

from __future__ import annotations

import asyncio
import base64
import concurrent.futures
import contextlib
import dataclasses
import functools
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypeVar

import numpy as np
import numpy.typing as npt
import structlog

from daemon.clock import RealClock, SessionClock
from daemon.config import Config
from daemon.errors import UsageError
from description.cell import CellLayout, Tray
from description.thesis import MugSpec, mug_catalogue
from drivers.dynamixel import BusConfig, DeviceEvent
from drivers.errors import BusLost, DriverError
from drivers.interfaces import (
    ArmDriver,
    Camera,
    DeviceHealth,
    ForceReading,
    ForceSensor,
    GraspResult,
    GripperDriver,
    GripperState,
    JointState,
    JointTrajectory,
)
from drivers.serial_port import OpenSerial
from drivers.stack import (
    ARM_JOINTS,
    DeviceStack,
    StackSpec,
    arm_joints,
    gripper_spec,
    open_device_stack,
)
from perception.interfaces import MugObserver, Observation
from planning.arm import ArmModel
from planning.arm.calibration import PositionCorrection
from planning.interfaces import CyclePlan, MotionPlanner, MotionRefused, MugPose, TraySlot
from planning.motion import DynamicsMoveCost, check_reachable
from planning.motion.planner import CyclePlanner
from planning.placement import PlacementPlanner, PlanOptions, PlanResult, Problem, plan
from wire.messages import BadMessage, Event, convert
from wire.motion import args_digest, result_json

if TYPE_CHECKING:
    from perception.calibration import CameraModel
    from recorder.foxglove_scene import SceneView

log = structlog.get_logger("daemon.backend")
T = TypeVar("T")


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
PlanPlacement = Callable[[PlacementPlanner, Problem, PlanOptions], Awaitable[PlanResult]]
# How a backend has placement planned: given the job's planner, the problem, the options and the job's own
# way of running a planner off the event loop.
PlacementRunner = Callable[[PlacementPlanner, Problem, PlanOptions, PlanPlacement], Awaitable[PlanResult]]


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
    # The devices' health, polled by the daemon, asked before a start and cleared on reset; None when the
    # backend has no devices of its own to check (the kinematic cell).
    health: DeviceHealth | None = None
    # The one clock everything of this backend and the job on it reads and waits on: the wall clock on the
    # robot, the simulated cell's clock in simulation.
    clock: SessionClock = field(default_factory=RealClock)
    # None: the job plans placements itself (in the planning process); a replay serves the recorded plans.
    placement: PlacementRunner | None = None

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
        """Release the devices. One that cannot be reached now (a silent servo, a pulled adapter: the arm
        cannot be relaxed) is logged, not raised: the others are released all the same, and the daemon's
        shutdown goes on to its end."""
        try:
            await self.closer()
        except (DriverError, BusLost) as e:
            log.error("device_close_failed", error=f"{type(e).__name__}: {e}")


Sink = Callable[[str, Mapping[str, object]], None]


class JobPosition:
    """Where the job is, for placing what comes from outside it (an operator's command, a device's event):
    the state, the transitions since the job's ``start`` (its own included) and the device commands the job
    gave since (moves, openings, closes, looks at the counter, stops: what the recorded arm, gripper and
    observer count). A replay sends such an input when its job is at the same place."""

    def __init__(self) -> None:
        self.state = "idle"
        self.transitions = 0
        self.device_commands = 0

    def saw(self, topic: str, payload: Mapping[str, object]) -> None:
        """Follow what the daemon publishes (its transitions)."""
        if topic != "events":
            return
        try:
            event = convert(payload, Event, name=topic)
        except BadMessage:
            return
        if event.kind != "transition":
            return
        if event.trigger == "start":
            self.transitions = 0
            self.device_commands = 0
        self.transitions += 1
        self.state = event.dest if isinstance(event.dest, str) else self.state

    def device_command(self) -> None:
        self.device_commands += 1

    def fields(self) -> dict[str, object]:
        return {
            "at_state": self.state,
            "at_transitions": self.transitions,
            "at_device_commands": self.device_commands,
        }


def recorded(backend: Backend, sink: Sink, position: JobPosition | None = None) -> Backend:
    """The same backend, with driver-boundary inputs also passed to ``sink(kind, payload)``: every read
    (and every read that failed), every device command, every device event (with the job's ``position``
    when it came), every motion plan."""
    clock = backend.clock
    where = position if position is not None else JobPosition()
    on_event = backend.on_event
    motion_for = backend.motion_for
    return replace(
        backend,
        arm=_RecordedArm(backend.arm, sink, clock, where),
        gripper=_RecordedGripper(backend.gripper, sink, clock, where),
        force=_RecordedForce(backend.force, sink, clock),
        observer=_RecordedObserver(backend.observer, sink, clock, where),
        motion=_RecordedMotion(backend.motion, sink, clock),
        motion_for=None
        if motion_for is None
        else lambda tray: _RecordedMotion(motion_for(tray), sink, clock),
        on_event=None if on_event is None else _recorded_events(on_event, sink, clock, where),
        health=None if backend.health is None else _RecordedHealth(backend.health, sink, clock),
    )


def _recorded_events(
    on_event: Callable[[EventListener], None], sink: Sink, clock: SessionClock, position: JobPosition
) -> Callable[[EventListener], None]:
    """``on_event`` whose events are also recorded (``input/device_event``) on the event loop, just before
    the daemon handles them there, with the job's position and the monotonic time then."""

    def register(listener: EventListener) -> None:
        try:
            loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            loop = None

        def record(event: Mapping[str, object]) -> None:
            sink("input/device_event", {**event, **position.fields(), "t_read": clock.monotonic()})

        def heard(event: Mapping[str, object]) -> None:  # possibly on a driver's thread
            if loop is None:
                record(event)
            else:
                with contextlib.suppress(RuntimeError):  # the loop is closed: the daemon is gone
                    loop.call_soon_threadsafe(record, dict(event))
            listener(event)

        on_event(heard)

    return register


def joints_payload(js: JointState, *, t: float, exact: bool = False) -> dict[str, object]:
    """``t`` is the clock's ``now()`` when published, ``t_device`` the driver's (monotonic) time;
    ``exact``: unrounded (a recorded input, which a replay hands the job again as it was)."""

    def r(v: float, digits: int) -> float:
        return v if exact else round(v, digits)

    return {
        "t": t,
        "t_device": js.t,
        "names": list(js.names),
        "position_rad": [r(v, 6) for v in js.position_rad],
        "velocity_rad_s": [r(v, 6) for v in js.velocity_rad_s],
        "load": [r(v, 4) for v in js.load],
    }


def observation_payload(obs: Observation, *, t: float, exact: bool = False) -> dict[str, object]:
    """``t`` is the clock's ``now()`` when published, ``t_device`` the observation's (monotonic) time;
    ``exact``: the detections unrounded (a recorded input)."""
    mugs = [d.to_json(exact=exact) for d in obs.detections]
    return {"t": t, "t_device": obs.t, "mugs": mugs, "meta": dict(obs.meta)}


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


def _failure(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}"


def failure_fields(e: BaseException) -> dict[str, object]:
    """A failed call's record: ``error`` (the type's name and the message), ``error_class`` (the type's
    module and name) and what the driver error carries besides its message (``servo_id``, ``bits``,
    ``port``), so that a replay raises the same error again."""
    out: dict[str, object] = {
        "error": _failure(e),
        "error_class": f"{type(e).__module__}.{type(e).__qualname__}",
    }
    for key in ("servo_id", "port"):
        value = getattr(e, key, None)
        if isinstance(value, str | int) and not isinstance(value, bool):
            out[f"error_{key}"] = value
    bits = getattr(e, "bits", None)
    if isinstance(bits, tuple) and all(isinstance(b, str) for b in bits):
        out["error_bits"] = list(bits)
    return out


async def _failing_recorded(
    call: Awaitable[T], sink: Sink, clock: SessionClock, topic: str, record: Mapping[str, object]
) -> T:
    """``await call``; when it is cancelled or raises, ``record`` goes to ``topic`` first, with the call's
    end and ``cancelled`` or the ``error``."""
    try:
        return await call
    except asyncio.CancelledError:
        sink(topic, {**record, "t_end": clock.monotonic(), "cancelled": True})
        raise
    except BaseException as e:
        sink(topic, {**record, "t_end": clock.monotonic(), **failure_fields(e)})
        raise


class _RecordedArm:
    def __init__(self, inner: ArmDriver, sink: Sink, clock: SessionClock, position: JobPosition) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock
        self._position = position

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._inner.joint_names

    async def read_joints(self) -> JointState:
        try:
            js = await self._inner.read_joints()
        except (DriverError, BusLost) as e:
            t_read = self._clock.monotonic()
            self._sink("input/joints_failed", {"t": self._clock.now(), "t_read": t_read, **failure_fields(e)})
            raise
        self._sink(
            "input/joints",
            {**joints_payload(js, t=self._clock.now(), exact=True), "t_read": self._clock.monotonic()},
        )
        return js

    async def follow(self, trajectory: JointTrajectory) -> None:
        """Recorded once done (or failed, or cancelled): what the daemon asked of the arm and how it went,
        so that a replay can tell whether it asks the same and take as long."""
        self._position.device_command()
        started = self._clock.monotonic()
        record: dict[str, object] = {
            "label": trajectory.label,
            "points": len(trajectory.times),
            "duration_s": round(trajectory.duration, 6),
            "end_rad": [round(float(v), 6) for v in trajectory.positions[-1]]
            if len(trajectory.times)
            else [],
            "t_start": started,
        }
        await _failing_recorded(
            self._inner.follow(trajectory), self._sink, self._clock, "output/follow", record
        )
        self._sink("output/follow", {**record, "t_end": self._clock.monotonic()})

    async def stop(self) -> None:
        self._position.device_command()
        self._sink("output/arm", {"action": "stop", "t_start": self._clock.monotonic()})
        await self._inner.stop()

    async def relax(self) -> None:
        self._position.device_command()
        self._sink("output/arm", {"action": "relax", "t_start": self._clock.monotonic()})
        await self._inner.relax()


class _RecordedGripper:
    def __init__(self, inner: GripperDriver, sink: Sink, clock: SessionClock, position: JobPosition) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock
        self._position = position

    async def read(self) -> GripperState:
        """Only the reads that failed are recorded: the job itself never reads the gripper (the telemetry
        does), so only a failure (which faults the job) is an input a replay needs."""
        try:
            return await self._inner.read()
        except (DriverError, BusLost) as e:
            t_read = self._clock.monotonic()
            self._sink(
                "input/gripper_failed", {"t": self._clock.now(), "t_read": t_read, **failure_fields(e)}
            )
            raise

    async def open(self, aperture_m: float | None = None) -> None:
        self._position.device_command()
        record: dict[str, object] = {
            "action": "open",
            "aperture_m": aperture_m,
            "t_start": self._clock.monotonic(),
        }
        await _failing_recorded(
            self._inner.open(aperture_m), self._sink, self._clock, "output/gripper", record
        )
        self._sink("output/gripper", {**record, "t_end": self._clock.monotonic()})

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        self._position.device_command()
        started = self._clock.monotonic()
        asked = {"force_threshold_n": force_threshold_n, "min_aperture_m": min_aperture_m, "t_start": started}
        closing = self._inner.close_on_mug(force_threshold_n=force_threshold_n, min_aperture_m=min_aperture_m)
        result = await _failing_recorded(closing, self._sink, self._clock, "input/grasp_failed", asked)
        self._sink(
            "input/grasp",
            {
                "held": result.held,
                "force_n": result.force_n,
                "aperture_m": result.aperture_m,
                "reason": result.reason,
                **asked,
                "t_end": self._clock.monotonic(),
            },
        )
        return result

    async def stop(self) -> None:
        self._position.device_command()
        self._sink("output/gripper", {"action": "stop", "t_start": self._clock.monotonic()})
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
                    "t_read": self._clock.monotonic(),
                    "force_n": reading.force_n,
                    "raw": reading.raw,
                    "seq": reading.seq,
                },
            )
        return reading

    def holding(self) -> bool:
        held = self._inner.holding()
        self._sink("input/holding", {"holding": held, "t_read": self._clock.monotonic()})
        return held


class _RecordedObserver:
    def __init__(self, inner: MugObserver, sink: Sink, clock: SessionClock, position: JobPosition) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock
        self._position = position

    async def observe(self) -> Observation:
        self._position.device_command()
        started = self._clock.monotonic()
        try:
            obs = await self._inner.observe()
        except asyncio.CancelledError:
            self._sink(
                "input/observe_failed",
                {
                    "t": self._clock.now(),
                    "t_start": started,
                    "t_end": self._clock.monotonic(),
                    "cancelled": True,
                },
            )
            raise
        except BaseException as e:
            self._sink(
                "input/observe_failed",
                {
                    "t": self._clock.now(),
                    "t_start": started,
                    "t_end": self._clock.monotonic(),
                    **failure_fields(e),
                },
            )
            raise
        self._sink(
            "input/observation",
            {
                **observation_payload(obs, t=self._clock.now(), exact=True),
                "t_start": started,
                "t_end": self._clock.monotonic(),
            },
        )
        return obs


class _RecordedHealth:
    """The devices' health, with every poll that raised recorded (``input/health_failed``)."""

    def __init__(self, inner: DeviceHealth, sink: Sink, clock: SessionClock) -> None:
        self._inner = inner
        self._sink = sink
        self._clock = clock

    @property
    def poll_period_s(self) -> float:
        return self._inner.poll_period_s

    async def poll(self) -> None:
        try:
            await self._inner.poll()
        except (DriverError, BusLost) as e:
            t_read = self._clock.monotonic()
            self._sink("input/health_failed", {"t": self._clock.now(), "t_read": t_read, **failure_fields(e)})
            raise

    def problems(self) -> tuple[str, ...]:
        return self._inner.problems()

    async def clear(self) -> tuple[str, ...]:
        return await self._inner.clear()


class MotionCalls:
    """A motion planner in front of another (``inner``): each of its three calls, with the arguments that
    name it, goes through ``_call(call, args, run)``, where ``run()`` asks the inner planner (the recorder
    records them, a replay serves recorded plans)."""

    inner: MotionPlanner

    def _call(self, call: str, args: tuple[object, ...], run: Callable[[], T]) -> T:
        raise NotImplementedError

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        return self._call(
            "plan_cycle",
            (tuple(start_q), mug, slot, tuple(on_tray), tuple(counter)),
            lambda: self.inner.plan_cycle(start_q, mug, slot, on_tray, counter=counter),
        )

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        return self._call(
            "plan_for_slot",
            (tuple(start_q), slot, tuple(counter), tuple(on_tray)),
            lambda: self.inner.plan_for_slot(start_q, slot, counter, on_tray),
        )

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        return self._call(
            "plan_move",
            (tuple(start_q), tuple(goal_q), label),
            lambda: self.inner.plan_move(start_q, goal_q, label=label),
        )


class _RecordedMotion(MotionCalls):
    """The motion planner, with each call's arguments (digest) and result recorded (``input/motion``,
    ``wire.motion``); called from the job's worker threads, as the planner is."""

    def __init__(self, inner: MotionPlanner, sink: Sink, clock: SessionClock) -> None:
        self.inner = inner
        self._sink = sink
        self._clock = clock

    def _call(self, call: str, args: tuple[object, ...], run: Callable[[], T]) -> T:
        record: dict[str, object] = {"call": call, "args_digest": args_digest(call, *args)}
        try:
            result = run()
        except MotionRefused as e:
            self._sink("input/motion", {**record, "refused": str(e), "blockers": sorted(e.blockers)})
            raise
        except Exception as e:
            self._sink("input/motion", {**record, **failure_fields(e)})
            raise
        self._sink("input/motion", {**record, "result": result_json(call, result)})
        return result


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
    reachable with every mug type of the catalogue (``planning.motion.check_reachable``)."""
    problems = check_reachable(config.cell, arm, config.mug_catalogue())
    if problems:
        raise UsageError(f"the arm cannot serve the configured cell: {'; '.join(problems)}")


@dataclass(frozen=True, slots=True)
class CyclePlannerSpec:
    """Everything needed to build the cycle planner, hashable and picklable, so that a planning process can
    build it once and reuse it: the cell, the tray the job fills (the cell's, or the one a simulated counter
    was set up with), the mug catalogue and the arm's position correction (``arm.calibration_file``)."""

    cell: CellLayout
    tray: Tray
    mug_types: tuple[MugSpec, ...]
    correction: PositionCorrection | None = None

    def layout(self) -> CellLayout:
        return self.cell.with_tray(self.tray)

    def catalogue(self) -> dict[str, MugSpec]:
        return mug_catalogue(self.mug_types)

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


def cycle_planner(
    config: Config, tray: Tray, *, arm: ArmModel, executor: concurrent.futures.Executor | None
) -> MotionPlanner:
    """The cycle planner every backend runs on: the configured cell with ``tray``, the configured catalogue
    and the arm's position correction; in ``executor`` (a process pool) when one is given."""
    spec = CyclePlannerSpec(config.cell, tray, config.mug_types, load_correction(config))
    return spec.build(arm) if executor is None else ProcessMotionPlanner(spec, executor)


@dataclass(frozen=True, slots=True)
class SimOptions:
    """The simulated cell ``dishbot run --sim`` and the benches ask for. ``world`` is ``kinematic`` (the fast
    placeholder) or ``mujoco`` (physics behind the real drivers); None takes ``sim.world``. ``transport``
    (MuJoCo cell; default ``sim.transport``) is ``inprocess`` (the drivers' bytes reach the simulators in
    this process, on simulated time) or ``pty`` (over pseudo-terminals, on the wall clock). How fast
    simulated time runs is the clock's business, not the cell's. ``dataset`` is set out on the counter;
    ``seed`` (default ``sim.seed``) seeds the detection noise; ``fsr_debounce_s`` is how long the MuJoCo
    cell's FSR reader waits before it believes a crossing (the reader's own default)."""

    world: str | None = None
    dataset: int = 1
    transport: str | None = None
    seed: int | None = None
    fsr_debounce_s: float = 0.03


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
        return StackSpec(
            bus=BusConfig(hw.servo_port, hw.baudrate, 1 if hw.protocol == 1 else 2),
            joints=joints,
            gripper=gripper,
            fsr=hw.fsr,
            retries=hw.retries,
            read_timeout_s=hw.read_timeout_s,
            health=hw.health,
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
    arm: ArmModel | None = None,
    executor: concurrent.futures.Executor | None = None,
    camera: Camera | None = None,
    clock: SessionClock | None = None,
    open_bus: OpenSerial | None = None,
    open_fsr: OpenSerial | None = None,
) -> Backend:
    """The robot: the device stack of ``[hardware]`` on its serial ports (the same stack the MuJoCo cell
    builds over its simulators) and the RealSense camera with the depth detector, on the wall clock
    (``clock``, default a ``RealClock``). ``camera`` replaces the configured camera (a stand-in for tests);
    ``open_bus`` and ``open_fsr`` open the ports instead of pyserial (the in-process simulators' cables,
    for tests on a simulated clock). A missing port, a missing pyrealsense2 or a servo chain that does not
    match the config is a one-line ``UsageError``. Call it on the event loop that will use the devices."""
    clock = clock or RealClock()
    hw = config.hardware
    ports = (("hardware.servo_port", hw.servo_port, open_bus), ("hardware.fsr.port", hw.fsr.port, open_fsr))
    for key, port, opener in ports:
        if opener is None and not Path(port).exists():  # noqa: ASYNC240 (one stat at start-up)
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
    arm_model = arm or ArmModel.load()
    spec = dataclasses.replace(hardware_stack_spec(config, arm_model), open_bus=open_bus, open_fsr=open_fsr)
    motion = cycle_planner(config, config.cell.tray, arm=arm_model, executor=executor)
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

    async def close() -> None:
        """Torque off and close the ports; a device that is already gone (unplugged, faulted) cannot be
        switched off and is only logged, so the daemon still exits cleanly."""
        try:
            await stack.aclose()
        except (DriverError, BusLost) as e:
            log.warning("device_close_failed", error=str(e))

    return Backend(
        name="hardware",
        arm=devices.arm,
        gripper=devices.gripper,
        force=devices.force,
        observer=observer,
        motion=motion,
        tray=config.cell.tray,
        closer=close,
        on_event=events.add,
        devices=devices,
        health=devices.health,
        clock=clock,
    )


def configured_camera_model(config: Config) -> CameraModel:
    """The camera as the config describes it: ``[camera]``'s image and pose, or its calibration file;
    ``ValueError`` (``CalibrationError``) naming what is wrong."""
    from perception.calibration import camera_model

    c = config.cell.camera
    return camera_model(
        width=c.width,
        height=c.height,
        fovy_deg=c.fovy_deg,
        position_m=c.position_m,
        yaw_rad=c.yaw_rad,
        pitch_rad=c.pitch_rad,
        calibration_file=config.camera.calibration_file,
    )


def scene_view(config: Config, *, depth_hz: float = 1.0) -> SceneView:
    """The Foxglove scene of the configured cell; without the camera (logged) when its model is unknown."""
    from perception.errors import CalibrationError
    from recorder.foxglove_scene import SceneView

    camera: CameraModel | None
    try:
        camera = configured_camera_model(config)
    except (CalibrationError, ValueError) as e:
        log.warning("foxglove_camera_unknown", error=str(e))
        camera = None
    return SceneView(config.mug_types, config.cell, camera=camera, depth_hz=depth_hz)


async def _hardware_observer(
    config: Config, stack: contextlib.AsyncExitStack, camera: Camera | None, clock: SessionClock
) -> MugObserver:
    """The mug observer on the configured camera: depth detection over the table, the tray left out."""
    from drivers.camera import RealSenseCamera
    from perception.observer import cell_observer_factory

    if camera is None and config.hardware.camera == "none":
        return _NoCamera(clock)
    try:
        model = configured_camera_model(config)
    except ValueError as e:
        raise UsageError(f"camera: {e}") from e
    if camera is None and config.hardware.camera == "zenoh":
        from daemon.zenoh_camera import CameraUnreachable, ZenohCamera

        source = config.hardware.zenoh_camera
        try:
            camera = await stack.enter_async_context(
                ZenohCamera(
                    connect=source.connect,
                    key=source.key,
                    intrinsics=model.intrinsics,
                    world_from_camera=model.world_from_camera,
                    clock=clock,
                )
            )
        except CameraUnreachable as e:
            raise UsageError(str(e)) from e
    if camera is None:
        camera = await stack.enter_async_context(
            RealSenseCamera(
                world_from_camera=model.world_from_camera,
                width=config.cell.camera.width,
                height=config.cell.camera.height,
                serial_number=config.hardware.camera_serial or None,
                clock=clock,
            )
        )
    factory = cell_observer_factory(
        config.cell, config.mug_catalogue(), clock=clock, limits=config.camera.frames
    )
    return factory(camera)
