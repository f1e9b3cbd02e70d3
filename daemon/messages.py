"""The wire messages the daemon builds from what its devices, observer, planners and job report, as the
declared structs of ``wire.messages``: joint states, gripper samples, observations, depth previews, plans,
failed calls; and device events, which stay mappings (a driver's event carries the driver's own keys first,
so no declared struct writes its bytes: README, "Zenoh key space").
"""

from __future__ import annotations

import base64
from typing import TypedDict

import numpy as np
import numpy.typing as npt

from drivers.dynamixel import DeviceEvent
from drivers.interfaces import ForceReading, GripperState, JointState
from perception.interfaces import Detection as SeenMug
from perception.interfaces import Observation as Look
from planning.placement import PlanResult
from wire.messages import (
    DepthPreview,
    Detection,
    Detections,
    Gripper,
    Joints,
    Observation,
    OutOfReach,
    PlacedMug,
    Plan,
    Slot,
)


def device_event_payload(event: DeviceEvent, *, t: float) -> dict[str, object]:
    """A driver's fault or recovery as published on ``events``: ``kind`` (``servo_fault``, ``bus_lost``,
    ``fsr_stale``, ...), ``device`` and its detail; ``t`` the clock's ``now()``, ``t_device`` the driver's
    clock."""
    detail = {
        k: v if isinstance(v, str | int | float | bool) or v is None else str(v)
        for k, v in event.detail.items()
    }
    return {**detail, "kind": event.kind, "device": event.device, "t": t, "t_device": event.t}


def joints_message(js: JointState, *, t: float) -> Joints:
    """``joints``: ``t`` is the clock's ``now()`` when published, ``t_device`` the driver's (monotonic)
    time; rounded to what a monitor needs (a recorded input is ``input_joints``)."""
    return Joints(
        t=t,
        t_device=js.t,
        names=list(js.names),
        position_rad=[round(v, 6) for v in js.position_rad],
        velocity_rad_s=[round(v, 6) for v in js.velocity_rad_s],
        load=[round(v, 4) for v in js.load],
    )


def gripper_message(gs: GripperState, reading: ForceReading | None, *, holding: bool, t: float) -> Gripper:
    """``gripper``: the gripper's state and the latest force reading (None: none yet), rounded."""
    return Gripper(
        t=t,
        t_device=gs.t,
        aperture_m=round(gs.aperture_m, 5),
        load=round(gs.load, 4),
        force_n=None if reading is None else round(reading.force_n, 4),
        raw=None if reading is None else reading.raw,
        seq=None if reading is None else reading.seq,
        holding=holding,
    )


def detection(d: SeenMug, *, exact: bool = False) -> Detection:
    """One seen mug, rounded to what a monitor needs; ``exact``: unrounded (a recorded input, which a
    replay hands the job again as it was)."""

    def r(v: float, digits: int) -> float:
        return v if exact else round(v, digits)

    return Detection(
        id=d.mug_id,
        type=d.type,
        x_m=r(d.x_m, 5),
        y_m=r(d.y_m, 5),
        upside_down=d.upside_down,
        handle_yaw_rad=r(d.handle_yaw_rad, 5),
        handle_seen=d.handle_seen,
        confidence=r(d.confidence, 4),
    )


def detections_message(obs: Look, *, t: float, depth_preview: DepthPreview | None = None) -> Detections:
    """``detections``: ``t`` is the clock's ``now()`` when published, ``t_device`` the observation's
    (monotonic) time; the mugs rounded."""
    mugs = [detection(d) for d in obs.detections]
    if depth_preview is None:
        return Detections(t=t, t_device=obs.t, mugs=mugs, meta=dict(obs.meta))
    return Detections(t=t, t_device=obs.t, mugs=mugs, meta=dict(obs.meta), depth_preview=depth_preview)


def observation_input(obs: Look, *, t: float, t_start: float, t_end: float) -> Observation:
    """``input/observation``: what the observer returned, unrounded, and when the look began and ended."""
    mugs = [detection(d, exact=True) for d in obs.detections]
    return Observation(t=t, t_device=obs.t, mugs=mugs, meta=dict(obs.meta), t_start=t_start, t_end=t_end)


def depth_preview(depth_m: npt.NDArray[np.float32]) -> DepthPreview:
    """A small depth image for monitors: unsigned 16-bit millimetres (0 = no reading), little-endian,
    row-major, base64."""
    mm = np.nan_to_num(np.asarray(depth_m, dtype=np.float64) * 1000.0, nan=0.0, posinf=0.0, neginf=0.0)
    data = np.clip(np.rint(mm), 0, 65535).astype("<u2")
    return DepthPreview(
        width=int(data.shape[1]),
        height=int(data.shape[0]),
        encoding="uint16_mm_le_base64",
        data=base64.b64encode(data.tobytes()).decode("ascii"),
    )


def plan_message(result: PlanResult, *, out_of_reach: list[OutOfReach], slots: list[Slot], t: float) -> Plan:
    """``plan``: the placement plan (``PlanResult.to_json``'s fields and rounding), the mugs left out
    because the arm cannot take them, the slots in placing order, ``t_plan_s`` the plan's time estimate and
    ``t`` the time of publication."""
    return Plan(
        method=result.method,
        heuristic=result.heuristic,
        sort=result.sort,
        fitness=result.fitness,
        cost_function=result.cost_function,
        seed=result.seed,
        wall_time_s=round(result.wall_time_s, 6),
        placed=[
            PlacedMug(
                id=p.id,
                type=p.type,
                x_mm=p.x_mm,
                y_mm=p.y_mm,
                rotated=p.rotated,
                order=p.order,
                brim_mm=None if p.brim_mm is None else [round(v, 3) for v in p.brim_mm],
                handle_yaw_rad=None if p.handle_yaw_rad is None else round(p.handle_yaw_rad, 6),
            )
            for p in result.placed
        ],
        unplaced=list(result.unplaced),
        n=result.n,
        A=result.A_mm2,
        E=round(result.E_j, 6),
        t=t,
        s=result.s,
        cost=round(result.cost, 6),
        optimal=result.optimal,
        upper_bound=result.upper_bound,
        gap=None if result.upper_bound is None else result.upper_bound - result.n,
        status=result.status,
        evaluations=result.evaluations,
        notes=list(result.notes),
        out_of_reach=out_of_reach,
        slots=slots,
        t_plan_s=round(result.t_s, 6),
    )


class FailureFields(TypedDict, total=False):
    """The fields of a failed call (``wire.messages.Failure``), as keywords for the message carrying them."""

    error: str
    error_class: str
    error_servo_id: int
    error_port: str
    error_bits: list[str]


def failure_fields(e: BaseException) -> FailureFields:
    """A failed call's record: ``error`` (the type's name and the message), ``error_class`` (the type's
    module and name) and what the driver error carries besides its message (``servo_id``, ``bits``,
    ``port``), so that a replay raises the same error again."""
    out = FailureFields(
        error=f"{type(e).__name__}: {e}", error_class=f"{type(e).__module__}.{type(e).__qualname__}"
    )
    servo_id = getattr(e, "servo_id", None)
    if isinstance(servo_id, int) and not isinstance(servo_id, bool):
        out["error_servo_id"] = servo_id
    port = getattr(e, "port", None)
    if isinstance(port, str):
        out["error_port"] = port
    bits = getattr(e, "bits", None)
    if isinstance(bits, tuple) and all(isinstance(b, str) for b in bits):
        out["error_bits"] = list(bits)
    return out
