"""A backend whose every input crossing the driver boundary (joint feedback, force readings, grasp results,
observations, device events, motion plans, failed calls) and every device command is also handed to the
recording (``recorded``): what a replay needs to hand the job the same again.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
from collections.abc import Awaitable, Callable, Iterator, Mapping
from dataclasses import replace
from typing import Final, TypeVar

import msgspec

from daemon.backend import Backend, EventListener
from daemon.clock import SessionClock
from daemon.messages import failure_fields, observation_input
from daemon.planners import MotionCalls
from drivers.errors import BusLost, DriverError
from drivers.interfaces import (
    ArmDriver,
    DeviceHealth,
    ForceReading,
    ForceSensor,
    GraspResult,
    GripperDriver,
    GripperState,
    JointState,
    JointTrajectory,
)
from perception.interfaces import MugObserver, Observation
from planning.interfaces import MotionPlanner, MotionRefused
from wire.messages import (
    ArmCommand,
    BadMessage,
    CallFailed,
    Event,
    Follow,
    Force,
    Grasp,
    GripperCommand,
    Holding,
    InputJoints,
    Motion,
    MotionCall,
    Payload,
    ReadFailed,
    as_message,
)
from wire.motion import args_digest, result_json

T = TypeVar("T")


Sink = Callable[[str, Payload], None]

# Who reads the arm's joints (``input/joints``'s ``reader``): the job (its plans and moves start from its own
# reads: ``daemon.job``) unless a reader says otherwise, as the telemetry's joints poll does
# (``daemon.app``). The two can read within milliseconds of each other, in either order: a replay hands each
# reader its own recorded samples, not whichever is nearest in time.
JOB_READER: Final = "job"
TELEMETRY_READER: Final = "telemetry"
_joint_reader: contextvars.ContextVar[str] = contextvars.ContextVar(
    "dishbot_joint_reader", default=JOB_READER
)


@contextlib.contextmanager
def joint_reader(name: str) -> Iterator[None]:
    """The arm's joints read within this block (in this task) are read by ``name``."""
    token = _joint_reader.set(name)
    try:
        yield
    finally:
        _joint_reader.reset(token)


def current_joint_reader() -> str:
    """Who reads the arm's joints now (``joint_reader``; the job by default)."""
    return _joint_reader.get()


class JobPosition:
    """Where the job is, for placing what comes from outside it (an operator's command, a device's event):
    the state, the transitions since the job's ``start`` (its own included) and the device commands the job
    gave since (moves, openings, closes, looks at the counter, stops: what the recorded arm, gripper and
    observer count). A replay sends such an input when its job is at the same place."""

    def __init__(self) -> None:
        self.state = "idle"
        self.transitions = 0
        self.device_commands = 0

    def saw(self, topic: str, payload: Payload) -> None:
        """Follow what the daemon publishes (its transitions)."""
        if topic != "events":
            return
        try:
            event = as_message(payload, Event, name=topic)
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
    the daemon handles them there, with the job's position and the monotonic time then. A device event is
    a mapping (the driver's own keys come first), so its record is one too."""

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


Ending = TypeVar("Ending", Follow, GripperCommand, CallFailed)


async def _failing_recorded(
    call: Awaitable[T], sink: Sink, clock: SessionClock, topic: str, record: Ending
) -> T:
    """``await call``; when it is cancelled or raises, ``record`` goes to ``topic`` first, with the call's
    end and ``cancelled`` or the ``error``."""
    try:
        return await call
    except asyncio.CancelledError:
        sink(topic, msgspec.structs.replace(record, t_end=clock.monotonic(), cancelled=True))
        raise
    except BaseException as e:
        sink(topic, msgspec.structs.replace(record, t_end=clock.monotonic(), **failure_fields(e)))
        raise


def _read_failed(clock: SessionClock, t_read: float, e: BaseException) -> ReadFailed:
    return ReadFailed(t=clock.now(), t_read=t_read, **failure_fields(e))


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
        reader = current_joint_reader()
        try:
            js = await self._inner.read_joints()
        except (DriverError, BusLost) as e:
            failed = msgspec.structs.replace(
                _read_failed(self._clock, self._clock.monotonic(), e), reader=reader
            )
            self._sink("input/joints_failed", failed)
            raise
        self._sink(
            "input/joints",
            InputJoints(
                t=self._clock.now(),
                t_device=js.t,
                names=list(js.names),
                position_rad=list(js.position_rad),
                velocity_rad_s=list(js.velocity_rad_s),
                load=list(js.load),
                t_read=self._clock.monotonic(),
                reader=reader,
            ),
        )
        return js

    async def follow(self, trajectory: JointTrajectory) -> None:
        """Recorded once done (or failed, or cancelled): what the daemon asked of the arm and how it went,
        so that a replay can tell whether it asks the same and take as long."""
        self._position.device_command()
        started = self._clock.monotonic()
        record = Follow(
            label=trajectory.label,
            points=len(trajectory.times),
            duration_s=round(trajectory.duration, 6),
            end_rad=[round(float(v), 6) for v in trajectory.positions[-1]] if len(trajectory.times) else [],
            t_start=started,
            t_end=started,  # until it ends
        )
        await _failing_recorded(
            self._inner.follow(trajectory), self._sink, self._clock, "output/follow", record
        )
        self._sink("output/follow", msgspec.structs.replace(record, t_end=self._clock.monotonic()))

    async def stop(self) -> None:
        self._position.device_command()
        self._sink("output/arm", ArmCommand(action="stop", t_start=self._clock.monotonic()))
        await self._inner.stop()

    async def relax(self) -> None:
        self._position.device_command()
        self._sink("output/arm", ArmCommand(action="relax", t_start=self._clock.monotonic()))
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
            self._sink("input/gripper_failed", _read_failed(self._clock, self._clock.monotonic(), e))
            raise

    async def open(self, aperture_m: float | None = None) -> None:
        self._position.device_command()
        record = GripperCommand(action="open", aperture_m=aperture_m, t_start=self._clock.monotonic())
        await _failing_recorded(
            self._inner.open(aperture_m), self._sink, self._clock, "output/gripper", record
        )
        self._sink("output/gripper", msgspec.structs.replace(record, t_end=self._clock.monotonic()))

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        self._position.device_command()
        started = self._clock.monotonic()
        asked = CallFailed(
            force_threshold_n=force_threshold_n,
            min_aperture_m=min_aperture_m,
            t_start=started,
            t_end=started,  # until it ends
        )
        closing = self._inner.close_on_mug(force_threshold_n=force_threshold_n, min_aperture_m=min_aperture_m)
        result = await _failing_recorded(closing, self._sink, self._clock, "input/grasp_failed", asked)
        self._sink(
            "input/grasp",
            Grasp(
                held=result.held,
                force_n=result.force_n,
                aperture_m=result.aperture_m,
                reason=result.reason,
                force_threshold_n=force_threshold_n,
                min_aperture_m=min_aperture_m,
                t_start=started,
                t_end=self._clock.monotonic(),
            ),
        )
        return result

    async def stop(self) -> None:
        self._position.device_command()
        self._sink("output/gripper", GripperCommand(action="stop", t_start=self._clock.monotonic()))
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
                Force(
                    t=self._clock.now(),
                    t_device=reading.t,
                    t_read=self._clock.monotonic(),
                    force_n=reading.force_n,
                    raw=reading.raw,
                    seq=reading.seq,
                ),
            )
        return reading

    def holding(self) -> bool:
        held = self._inner.holding()
        self._sink("input/holding", Holding(holding=held, t_read=self._clock.monotonic()))
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
                CallFailed(
                    t=self._clock.now(), t_start=started, t_end=self._clock.monotonic(), cancelled=True
                ),
            )
            raise
        except BaseException as e:
            self._sink(
                "input/observe_failed",
                CallFailed(
                    t=self._clock.now(), t_start=started, t_end=self._clock.monotonic(), **failure_fields(e)
                ),
            )
            raise
        self._sink(
            "input/observation",
            observation_input(obs, t=self._clock.now(), t_start=started, t_end=self._clock.monotonic()),
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
            self._sink("input/health_failed", _read_failed(self._clock, self._clock.monotonic(), e))
            raise

    def problems(self) -> tuple[str, ...]:
        return self._inner.problems()

    async def clear(self) -> tuple[str, ...]:
        return await self._inner.clear()


class _RecordedMotion(MotionCalls):
    """The motion planner, with each call's arguments (digest) and result recorded (``input/motion``,
    ``wire.motion``); called from the job's worker threads, as the planner is."""

    def __init__(self, inner: MotionPlanner, sink: Sink, clock: SessionClock) -> None:
        self.inner = inner
        self._sink = sink
        self._clock = clock

    def _call(self, call: MotionCall, args: tuple[object, ...], run: Callable[[], T]) -> T:
        digest = args_digest(call, *args)
        try:
            result = run()
        except MotionRefused as e:
            self._sink(
                "input/motion",
                Motion(call=call, args_digest=digest, refused=str(e), blockers=sorted(e.blockers)),
            )
            raise
        except Exception as e:
            self._sink("input/motion", Motion(call=call, args_digest=digest, **failure_fields(e)))
            raise
        self._sink("input/motion", Motion(call=call, args_digest=digest, result=result_json(call, result)))
        return result
