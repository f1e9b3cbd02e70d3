"""What a loading job runs on: the devices, the observer and the motion planner, bundled as a ``Backend``.

The job runner only sees the protocols of ``drivers.interfaces``, ``perception.interfaces`` and
``planning.interfaces``. ``open_backend`` builds the bundle the configuration asks for; ``recorded`` wraps one
so that every input crossing the driver boundary (joint feedback, force readings, grasp results, observations)
is also handed to the recording, which is what a replay needs.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

from drivers.interfaces import (
    ArmDriver,
    ForceReading,
    ForceSensor,
    GraspResult,
    GripperDriver,
    GripperState,
    JointState,
    JointTrajectory,
)
from perception.interfaces import MugObserver, Observation
from planning.interfaces import MotionPlanner


@dataclass(frozen=True, slots=True)
class Tray:
    """The tray in the world frame: the corner nearest the arm base, and its extent in mm (as planned)."""

    origin_m: tuple[float, float]
    size_mm: tuple[int, int]


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
    return replace(
        backend,
        arm=_RecordedArm(backend.arm, sink),
        gripper=_RecordedGripper(backend.gripper, sink),
        force=_RecordedForce(backend.force, sink),
        observer=_RecordedObserver(backend.observer, sink),
    )


def joints_payload(js: JointState) -> dict[str, object]:
    return {
        "t": js.t,
        "names": list(js.names),
        "position_rad": [round(v, 6) for v in js.position_rad],
        "velocity_rad_s": [round(v, 6) for v in js.velocity_rad_s],
        "load": [round(v, 4) for v in js.load],
    }


def observation_payload(obs: Observation) -> dict[str, object]:
    return {"t": obs.t, "mugs": [d.to_json() for d in obs.detections], "meta": dict(obs.meta)}


class _RecordedArm:
    def __init__(self, inner: ArmDriver, sink: Sink) -> None:
        self._inner = inner
        self._sink = sink

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._inner.joint_names

    async def read_joints(self) -> JointState:
        js = await self._inner.read_joints()
        self._sink("input/joints", joints_payload(js))
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

    async def open(self) -> None:
        await self._inner.open()

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
    def __init__(self, inner: ForceSensor, sink: Sink) -> None:
        self._inner = inner
        self._sink = sink

    def latest(self) -> ForceReading | None:
        reading = self._inner.latest()
        if reading is not None:
            self._sink(
                "input/force",
                {"t": reading.t, "force_n": reading.force_n, "raw": reading.raw, "seq": reading.seq},
            )
        return reading

    def holding(self) -> bool:
        held = self._inner.holding()
        self._sink("input/holding", {"holding": held})
        return held


class _RecordedObserver:
    def __init__(self, inner: MugObserver, sink: Sink) -> None:
        self._inner = inner
        self._sink = sink

    async def observe(self) -> Observation:
        obs = await self._inner.observe()
        self._sink("input/observation", observation_payload(obs))
        return obs
