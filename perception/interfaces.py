"""The seams between perception and the rest: what the daemon asks of "seeing the counter" (``MugObserver``)
and of telling which mug seen now is which mug seen before (``Associate``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, slots=True)
class Detection:
    """One mug seen on the counter, in the world frame (x forward, y left, z up; metres, radians)."""

    type: str  # a name from the configured mug catalogue
    x_m: float  # mug axis on the table
    y_m: float
    upside_down: bool
    handle_yaw_rad: float  # direction of the handle from the mug axis, about +z
    confidence: float  # 0..1
    mug_id: str = ""  # stable id once associated with a known mug
    # False when the handle was hidden (behind the mug or another one): handle_yaw_rad is then a guess,
    # pointing away from the camera, and the arm cannot tell where the handle will land on the tray.
    handle_seen: bool = True

    def to_json(self, *, exact: bool = False) -> dict[str, object]:
        """For publishing, rounded to what a monitor needs; ``exact`` for a recording's inputs, which a
        replay hands the job again as they were."""

        def r(v: float, digits: int) -> float:
            return v if exact else round(v, digits)

        return {
            "id": self.mug_id,
            "type": self.type,
            "x_m": r(self.x_m, 5),
            "y_m": r(self.y_m, 5),
            "upside_down": self.upside_down,
            "handle_yaw_rad": r(self.handle_yaw_rad, 5),
            "handle_seen": self.handle_seen,
            "confidence": r(self.confidence, 4),
        }


@dataclass(frozen=True, slots=True)
class Observation:
    """What one look at the counter produced."""

    t: float
    detections: tuple[Detection, ...]
    # A small depth image (metres, float32) for monitoring and recording; None when the source has none.
    depth_preview: npt.NDArray[np.float32] | None = None
    meta: dict[str, str] = field(default_factory=dict)


@runtime_checkable
class MugObserver(Protocol):
    """Looks at the counter and reports the mugs on it."""

    async def observe(self) -> Observation: ...


class Associate(Protocol):
    """Lost-mug association (``perception.associate``): the seen detections, each with the id of the known
    mug it is ("" when new). ``target_id`` names the mug the arm was handling (it may have moved)."""

    def __call__(
        self, known: Sequence[Detection], seen: Sequence[Detection], *, target_id: str = ""
    ) -> Sequence[Detection]: ...
