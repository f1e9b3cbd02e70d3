"""Motion plans on the wire: what the ``input/motion`` topic records of each call the job made to its motion
planner, so that a replay can hand the job the same plans instead of planning again.

A record names the call (``plan_cycle``, ``plan_for_slot`` or ``plan_move``), a digest of its arguments
(``args_digest``: SHA-256 over their canonical JSON, every float written exactly) and the result: a cycle
plan, a mug and its cycle plan, or one trajectory; or ``refused`` (the ``MotionRefused`` message) with its
``blockers``. A trajectory's times and positions are float64, little-endian, row-major, base64: exact (a
replay's arm then follows what the recorded arm was given, bit for bit) and about a third of the JSON text.
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import json
from collections.abc import Sequence
from typing import Any, ClassVar, Final, TypeVar

import msgspec
import numpy as np

from drivers.interfaces import JointTrajectory
from planning.interfaces import CyclePlan, MugPose, Step, StepKind
from validation import UNKNOWN_KEYS_IGNORED, convert

ENCODING: Final = "float64_le_base64"
CALLS: Final = ("plan_cycle", "plan_for_slot", "plan_move")


class BadMotionRecord(ValueError):
    """A recorded motion result that cannot be read back; the message says what is wrong."""


# Arguments are compared to this many decimals (radians, metres): what a recorded plan keeps of a slot's
# handle yaw (six), far below anything a plan could tell apart.
DIGITS: Final = 6


def args_digest(call: str, *args: object) -> str:
    """A digest of a planner call's arguments (floats to ``DIGITS`` decimals): equal when the job asked for
    the same plan."""
    text = json.dumps([call, *(_plain(a) for a in args)], sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _plain(value: object) -> object:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, bool | str | int) or value is None:
        return value
    if isinstance(value, float | np.floating):
        return round(float(value), DIGITS) + 0.0  # no -0.0
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, Sequence):
        return [_plain(v) for v in value]
    raise TypeError(f"a motion planner argument of type {type(value).__name__}")


def _array(values: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f8").tobytes()).decode("ascii")


def _floats(text: str, what: str) -> np.ndarray:
    try:
        data = base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError) as e:
        raise BadMotionRecord(f"{what} is not base64: {e}") from e
    if len(data) % 8:
        raise BadMotionRecord(f"{what} is {len(data)} bytes, not whole float64 values")
    return np.frombuffer(data, dtype="<f8").astype(np.float64)


# How a recorded result is read back: typed views of the result's JSON (``Motion.result``), checked by the
# one validator. They are not a topic's declared type: ``input/motion``'s schema keeps ``result`` an object.
# Keys a later version adds are let through unread, as on every recorded message.


class TrajectoryView(msgspec.Struct, kw_only=True):
    """A recorded trajectory: joint names, and times and positions as ``ENCODING`` text."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    names: list[str]
    times: str
    positions: str
    label: str = ""


class StepView(msgspec.Struct, kw_only=True):
    """A recorded cycle plan's step."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    kind: StepKind
    phase: str = ""
    trajectory: TrajectoryView | None = None
    aperture_m: float | None = None


class CyclePlanView(msgspec.Struct, kw_only=True):
    """A recorded cycle plan."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    steps: list[StepView]
    duration_s: float
    energy_j: float
    mug_id: str = ""
    handle_yaw_rad: float | None = None


class MugPoseView(msgspec.Struct, kw_only=True):
    """A recorded mug pose (``plan_for_slot``'s mug)."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    x_m: float
    y_m: float
    handle_yaw_rad: float
    mug_id: str = ""
    type: str = ""
    upside_down: bool = False
    handle_seen: bool = True


class SlotResultView(msgspec.Struct, kw_only=True):
    """A recorded ``plan_for_slot`` result: the mug as the planner took it, and its cycle plan."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    mug: MugPoseView
    plan: CyclePlanView


View = TypeVar("View", TrajectoryView, CyclePlanView, MugPoseView, SlotResultView)


def _view(doc: object, kind: type[View], name: str) -> View:
    """``doc`` read as ``kind``; ``BadMotionRecord`` (one line naming the field) when it is not one."""
    return convert(doc, kind, name=name, error=BadMotionRecord, root=name)


def trajectory_json(traj: JointTrajectory) -> dict[str, object]:
    return {
        "label": traj.label,
        "names": list(traj.names),
        "encoding": ENCODING,
        "times": _array(np.asarray(traj.times)),
        "positions": _array(np.asarray(traj.positions)),
    }


def _trajectory(view: TrajectoryView) -> JointTrajectory:
    times = _floats(view.times, "a trajectory's times")
    positions = _floats(view.positions, "a trajectory's positions")
    names = view.names
    if len(positions) != len(times) * len(names):
        raise BadMotionRecord(
            f"a trajectory has {len(times)} times and {len(positions)} positions for {len(names)} joints"
        )
    return JointTrajectory(tuple(names), times, positions.reshape(len(times), len(names)), label=view.label)


def cycle_plan_json(plan: CyclePlan) -> dict[str, object]:
    steps: list[dict[str, object]] = []
    for s in plan.steps:
        step: dict[str, object] = {"phase": s.phase, "kind": str(s.kind)}
        if s.trajectory is not None:
            step["trajectory"] = trajectory_json(s.trajectory)
        if s.aperture_m is not None:
            step["aperture_m"] = s.aperture_m
        steps.append(step)
    return {
        "mug_id": plan.mug_id,
        "steps": steps,
        "duration_s": plan.duration_s,
        "energy_j": plan.energy_j,
        "handle_yaw_rad": plan.handle_yaw_rad,
    }


def _cycle_plan(view: CyclePlanView) -> CyclePlan:
    steps = tuple(
        Step(s.phase, s.kind, None if s.trajectory is None else _trajectory(s.trajectory), s.aperture_m)
        for s in view.steps
    )
    return CyclePlan(
        mug_id=view.mug_id,
        steps=steps,
        duration_s=view.duration_s,
        energy_j=view.energy_j,
        handle_yaw_rad=view.handle_yaw_rad,
    )


def mug_pose_json(mug: MugPose) -> dict[str, object]:
    return {f.name: getattr(mug, f.name) for f in dataclasses.fields(mug)}


def _mug_pose(view: MugPoseView) -> MugPose:
    return MugPose(
        mug_id=view.mug_id,
        type=view.type,
        x_m=view.x_m,
        y_m=view.y_m,
        handle_yaw_rad=view.handle_yaw_rad,
        upside_down=view.upside_down,
        handle_seen=view.handle_seen,
    )


def result_json(call: str, result: object) -> dict[str, Any]:
    """The JSON of a planner call's result."""
    if call == "plan_move" and isinstance(result, JointTrajectory):
        return trajectory_json(result)
    if call == "plan_cycle" and isinstance(result, CyclePlan):
        return cycle_plan_json(result)
    if call == "plan_for_slot" and isinstance(result, tuple) and len(result) == 2:
        mug, plan = result
        if isinstance(mug, MugPose) and isinstance(plan, CyclePlan):
            return {"mug": mug_pose_json(mug), "plan": cycle_plan_json(plan)}
    raise TypeError(f"{call} returned {type(result).__name__}")


def result_from_json(call: str, doc: object) -> JointTrajectory | CyclePlan | tuple[MugPose, CyclePlan]:
    """A planner call's result read back (``BadMotionRecord`` when it cannot be)."""
    name = f"{call} result"
    if call == "plan_move":
        return _trajectory(_view(doc, TrajectoryView, name))
    if call == "plan_cycle":
        return _cycle_plan(_view(doc, CyclePlanView, name))
    if call == "plan_for_slot":
        slot = _view(doc, SlotResultView, name)
        return _mug_pose(slot.mug), _cycle_plan(slot.plan)
    raise BadMotionRecord(f"unknown planner call {call!r}")


__all__ = [
    "CALLS",
    "BadMotionRecord",
    "args_digest",
    "result_from_json",
    "result_json",
]
