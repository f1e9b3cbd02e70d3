"""The placeholder detector: the simulation's true mug poses with seeded Gaussian noise.

Stands in for depth-based detection while the cell is simulated without a camera. It reports what a camera
would report: no ids (association gives those), noisy positions and handle directions, confidence below 1.
``FaultyObserver`` wraps an observer with the camera's faults, for replays and fault files.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from drivers.camera.realsense import CameraUnavailable
from drivers.interfaces import Clock
from drivers.sim.camera import CAMERA_FAULTS, CameraFault
from perception.errors import FrameError
from perception.interfaces import Detection, MugObserver, Observation


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


class FaultyObserver:
    """A ``MugObserver`` whose camera can fail, for the kinematic cell, which has no camera to fail: each
    fault shows as the camera driver and the depth detector on the robot would show it.

    ``no_frame`` waits the camera's frame timeout and raises the RealSense driver's ``CameraUnavailable``;
    ``stale`` returns the last observation again, with its old ``t``; ``bad_frame`` raises the detector's
    ``FrameError`` for a depth image without valid pixels; ``hang`` does not return until cleared."""

    def __init__(self, inner: MugObserver, *, clock: Clock, timeout_s: float = 1.0) -> None:
        self._inner = inner
        self._clock = clock
        self.timeout_s = timeout_s
        self.fault: CameraFault | None = None
        self._last: Observation | None = None
        self._cleared: asyncio.Event | None = None
        self.faulty_captures = 0

    def set_fault(self, fault: CameraFault) -> None:
        if fault not in CAMERA_FAULTS:
            raise ValueError(f"camera fault {fault!r}: choose one of {', '.join(CAMERA_FAULTS)}")
        self.fault = fault

    def clear(self) -> None:
        self.fault = None
        if self._cleared is not None:
            self._cleared.set()
            self._cleared = None

    async def observe(self) -> Observation:
        fault = self.fault
        if fault is not None:
            self.faulty_captures += 1
        if fault == "hang":
            while self.fault == "hang":
                if self._cleared is None:
                    self._cleared = asyncio.Event()
                await self._cleared.wait()
        elif fault == "no_frame":
            await self._clock.sleep(self.timeout_s)
            raise CameraUnavailable(
                f"the RealSense camera sent no frame within {self.timeout_s:.1f} s: Frame didn't arrive "
                f"within {round(self.timeout_s * 1000)}"
            )
        elif fault == "stale" and self._last is not None:
            return self._last
        elif fault == "bad_frame":
            raise FrameError("the depth image has only 0 valid pixels; is the camera covered?")
        self._last = await self._inner.observe()
        return self._last
