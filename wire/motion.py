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
from collections.abc import Mapping, Sequence
from typing import Any, Final

import numpy as np

from drivers.interfaces import JointTrajectory
from planning.interfaces import CyclePlan, MugPose, Step, StepKind

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


def _floats(text: object, what: str) -> np.ndarray:
    if not isinstance(text, str):
        raise BadMotionRecord(f"{what} is not {ENCODING} text")
    try:
        data = base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError) as e:
        raise BadMotionRecord(f"{what} is not base64: {e}") from e
    if len(data) % 8:
        raise BadMotionRecord(f"{what} is {len(data)} bytes, not whole float64 values")
    return np.frombuffer(data, dtype="<f8").astype(np.float64)


def trajectory_json(traj: JointTrajectory) -> dict[str, object]:
    return {
        "label": traj.label,
        "names": list(traj.names),
        "encoding": ENCODING,
        "times": _array(np.asarray(traj.times)),
        "positions": _array(np.asarray(traj.positions)),
    }


def trajectory_from_json(doc: object) -> JointTrajectory:
    if not isinstance(doc, Mapping):
        raise BadMotionRecord("a trajectory is not an object")
    names = doc.get("names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise BadMotionRecord("a trajectory's names are not a list of strings")
    times = _floats(doc.get("times"), "a trajectory's times")
    positions = _floats(doc.get("positions"), "a trajectory's positions")
    if len(positions) != len(times) * len(names):
        raise BadMotionRecord(
            f"a trajectory has {len(times)} times and {len(positions)} positions for {len(names)} joints"
        )
    return JointTrajectory(
        tuple(names),
        times,
        positions.reshape(len(times), len(names)),
        label=str(doc.get("label", "")),
    )


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


def cycle_plan_from_json(doc: object) -> CyclePlan:
    if not isinstance(doc, Mapping) or not isinstance(doc.get("steps"), list):
        raise BadMotionRecord("a cycle plan is not an object with steps")
    steps: list[Step] = []
    for s in doc["steps"]:
        if not isinstance(s, Mapping):
            raise BadMotionRecord("a cycle plan's step is not an object")
        try:
            kind = StepKind(str(s.get("kind")))
        except ValueError as e:
            raise BadMotionRecord(f"a cycle plan's step has kind {s.get('kind')!r}") from e
        traj = s.get("trajectory")
        aperture = s.get("aperture_m")
        steps.append(
            Step(
                str(s.get("phase", "")),
                kind,
                None if traj is None else trajectory_from_json(traj),
                float(aperture) if isinstance(aperture, int | float) else None,
            )
        )
    yaw = doc.get("handle_yaw_rad")
    return CyclePlan(
        mug_id=str(doc.get("mug_id", "")),
        steps=tuple(steps),
        duration_s=_number(doc, "duration_s"),
        energy_j=_number(doc, "energy_j"),
        handle_yaw_rad=float(yaw) if isinstance(yaw, int | float) else None,
    )


def mug_pose_json(mug: MugPose) -> dict[str, object]:
    return {f.name: getattr(mug, f.name) for f in dataclasses.fields(mug)}


def mug_pose_from_json(doc: object) -> MugPose:
    if not isinstance(doc, Mapping):
        raise BadMotionRecord("a mug pose is not an object")
    return MugPose(
        mug_id=str(doc.get("mug_id", "")),
        type=str(doc.get("type", "")),
        x_m=_number(doc, "x_m"),
        y_m=_number(doc, "y_m"),
        handle_yaw_rad=_number(doc, "handle_yaw_rad"),
        upside_down=bool(doc.get("upside_down", False)),
        handle_seen=bool(doc.get("handle_seen", True)),
    )


def _number(doc: Mapping[str, object], key: str) -> float:
    value = doc.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BadMotionRecord(f"{key} is {value!r}, not a number")
    return float(value)


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
    if call == "plan_move":
        return trajectory_from_json(doc)
    if call == "plan_cycle":
        return cycle_plan_from_json(doc)
    if call == "plan_for_slot":
        if not isinstance(doc, Mapping):
            raise BadMotionRecord("a plan_for_slot result is not an object")
        return mug_pose_from_json(doc.get("mug")), cycle_plan_from_json(doc.get("plan"))
    raise BadMotionRecord(f"unknown planner call {call!r}")


__all__ = [
    "CALLS",
    "BadMotionRecord",
    "args_digest",
    "result_from_json",
    "result_json",
]
