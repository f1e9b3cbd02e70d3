"""The placeholder detector: the simulation's true mug poses with seeded Gaussian noise.

Stands in for depth-based detection while the cell is simulated without a camera. It reports what a camera
would report: no ids (association gives those), noisy positions and handle directions, confidence below 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from drivers.interfaces import Clock
from perception.interfaces import Detection, Observation


class TruthObserver:
    """A ``MugObserver`` over ``truth()``, which returns the exact detections of the mugs in view; an
    observation's ``t`` is ``clock``'s."""

    def __init__(
        self,
        truth: Callable[[], Sequence[Detection]],
        *,
        clock: Clock,
        noise_m: float,
        yaw_noise_rad: float = math.radians(2.0),
        seed: int = 0,
    ) -> None:
        if noise_m < 0 or yaw_noise_rad < 0:
            raise ValueError(
                f"noise must be non-negative, got noise_m={noise_m}, yaw_noise_rad={yaw_noise_rad}"
            )
        self._truth = truth
        self._clock = clock
        self._noise_m = noise_m
        self._yaw_noise_rad = yaw_noise_rad
        self._rng = np.random.default_rng(seed)

    async def observe(self) -> Observation:
        seen = []
        for d in self._truth():
            dx, dy = self._rng.normal(0.0, self._noise_m, 2) if self._noise_m else (0.0, 0.0)
            dyaw = float(self._rng.normal(0.0, self._yaw_noise_rad)) if self._yaw_noise_rad else 0.0
            confidence = float(np.clip(1.0 - abs(self._rng.normal(0.0, 0.03)), 0.5, 1.0))
            seen.append(
                replace(
                    d,
                    x_m=d.x_m + float(dx),
                    y_m=d.y_m + float(dy),
                    handle_yaw_rad=d.handle_yaw_rad + dyaw,
                    confidence=confidence,
                    mug_id="",
                )
            )
        return Observation(t=self._clock.monotonic(), detections=tuple(seen), meta={"source": "truth"})
