"""The wire messages the daemon builds from what its devices, observer and job report (``wire.messages``
declares them): joint states, observations, depth previews, device events and failed calls.
"""

from __future__ import annotations

import base64
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from drivers.dynamixel import DeviceEvent
from drivers.interfaces import (
    JointState,
)
from perception.interfaces import Observation

T = TypeVar("T")


def device_event_payload(event: DeviceEvent, *, t: float) -> dict[str, object]:
    """A driver's fault or recovery as published on ``events``: ``kind`` (``servo_fault``, ``bus_lost``,
    ``fsr_stale``, ...), ``device`` and its detail; ``t`` the clock's ``now()``, ``t_device`` the driver's
    clock."""
    detail = {
        k: v if isinstance(v, str | int | float | bool) or v is None else str(v)
        for k, v in event.detail.items()
    }
    return {**detail, "kind": event.kind, "device": event.device, "t": t, "t_device": event.t}


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
