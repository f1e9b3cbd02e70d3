"""The kinematic cell's camera and detector: the simulation's true mug poses, behind the camera driver's
checks.

The kinematic world has nothing to render. ``TruthCamera`` is its ``drivers.interfaces.Camera``: each capture
is a small flat depth frame stamped on the clock and numbered in its ``meta`` (``truth_frame``), and the
camera keeps the mugs that were in view when it was taken. ``TruthDetector`` is the detector perception's
``CameraObserver`` runs on a frame: it reports the mugs that frame saw, with seeded Gaussian noise, as a
camera would (no ids, association gives those; noisy positions and handle directions; confidence below 1).

So the kinematic cell observes as the MuJoCo cell and the robot do: the frame checks of ``CameraObserver``
(``FrameLimits``: the timeout, the age limit, a bad frame, the retries) and the camera fault model of
``drivers.sim.camera.FaultyCamera`` act on these frames; a stale frame shows the mugs as they stood when it
was taken.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from description.camera import CameraIntrinsics
from description.thesis import MugSpec
from drivers.interfaces import Clock, RGBDFrame
from perception.detector import DepthMugDetector
from perception.errors import FrameError
from perception.interfaces import Detection

FRAME_KEY = "truth_frame"  # the frame's number in its meta
_KEEP = 64  # frames whose view the camera remembers (a stale frame is the last good one)


class TruthCamera:
    """A camera over ``truth()`` (the exact detections of the mugs in view): ``width`` x ``height`` frames of
    a flat table 1 m away, stamped with ``clock``'s ``monotonic``."""

    def __init__(
        self, truth: Callable[[], Sequence[Detection]], *, clock: Clock, width: int = 16, height: int = 12
    ) -> None:
        self._truth = truth
        self._clock = clock
        self.intrinsics = CameraIntrinsics(width, height, float(width), float(width), width / 2, height / 2)
        self._depth = np.ones((height, width), dtype=np.float32)
        self._depth.flags.writeable = False
        self._pose = np.eye(4)
        self._pose.flags.writeable = False
        self._seen: OrderedDict[int, tuple[Detection, ...]] = OrderedDict()
        self._frames = 0

    async def capture(self) -> RGBDFrame:
        self._frames += 1
        self._seen[self._frames] = tuple(self._truth())
        while len(self._seen) > _KEEP:
            self._seen.popitem(last=False)
        return RGBDFrame(
            t=self._clock.monotonic(),
            depth_m=self._depth,
            intrinsics=self.intrinsics,
            world_from_camera=self._pose,
            meta={FRAME_KEY: str(self._frames)},
        )

    def seen(self, frame: RGBDFrame) -> tuple[Detection, ...]:
        """The mugs in view when ``frame`` was taken; ``FrameError`` for a frame this camera did not take."""
        number = frame.meta.get(FRAME_KEY)
        try:
            return self._seen[int(number or "")]
        except (KeyError, ValueError):
            raise FrameError(f"frame {number!r} was not taken by the kinematic cell's camera") from None


class TruthDetector(DepthMugDetector):
    """The detector for ``camera``'s frames: what each frame saw, with position noise ``noise_m`` (standard
    deviation, metres) and handle-direction noise ``yaw_noise_rad``, seeded with ``seed``."""

    def __init__(
        self,
        camera: TruthCamera,
        catalogue: Mapping[str, MugSpec],
        *,
        noise_m: float,
        yaw_noise_rad: float = math.radians(2.0),
        seed: int = 0,
    ) -> None:
        if noise_m < 0 or yaw_noise_rad < 0:
            raise ValueError(
                f"noise must be non-negative, got noise_m={noise_m}, yaw_noise_rad={yaw_noise_rad}"
            )
        super().__init__(catalogue)
        self._camera = camera
        self._noise_m = noise_m
        self._yaw_noise_rad = yaw_noise_rad
        self._rng = np.random.default_rng(seed)

    def detect(self, frame: RGBDFrame) -> list[Detection]:
        seen = []
        for d in self._camera.seen(frame):
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
        return seen
