"""The daemon's eyes: capture a depth frame, detect the mugs off the event loop, keep a small preview.

The observer is where a failing camera is caught: a capture that does not return in time, a frame older
than allowed, a frame that cannot be a depth image (wrong shape, NaN depth, no valid pixels, no table in
view). Each is retried a bounded number of times (``FrameLimits``, in ``perception.frames``); then
``observe`` raises ``CameraFault`` naming the last reason, and the job faults with it.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Executor

import cv2
import numpy as np
import numpy.typing as npt
import structlog

from description.cell import CellLayout
from description.thesis import MUG_TYPES, MugSpec
from drivers.errors import DriverError
from drivers.interfaces import Camera, Clock, RGBDFrame
from perception.detector import DepthMugDetector
from perception.errors import CameraFault, FrameError
from perception.frames import FrameLimits as FrameLimits  # where the cells and tests find it
from perception.interfaces import Detection, Observation

log = structlog.get_logger(__name__)


class CameraObserver:
    """Implements ``perception.interfaces.MugObserver`` on a depth camera and the depth mug detector.

    Detection (tens of milliseconds of numpy) runs in ``executor`` (the loop's default thread pool when None)
    so the event loop keeps publishing telemetry meanwhile. The capture itself is awaited on the loop: a
    simulated camera renders on the thread that owns its GL context. Without a detector, one for the
    thesis's two mug types searches the whole table in view. Frames are held to ``limits``; the timeout and
    the age are measured on ``clock`` (without one, frames may take as long as the camera takes and be of
    any age; they are still checked and retried).
    """

    def __init__(
        self,
        camera: Camera,
        detector: DepthMugDetector | None = None,
        *,
        preview_width: int = 160,
        executor: Executor | None = None,
        clock: Clock | None = None,
        limits: FrameLimits | None = None,
    ) -> None:
        if preview_width < 8:
            raise ValueError(f"preview_width {preview_width}: use at least 8 pixels")
        self._camera = camera
        self._detector = detector or DepthMugDetector(MUG_TYPES)
        self._preview_width = preview_width
        self._executor = executor
        self._clock = clock
        self._limits = limits or FrameLimits()

    @property
    def detector(self) -> DepthMugDetector:
        """The detector the observer runs on each frame (its catalogue, region and exclusions)."""
        return self._detector

    async def observe(self) -> Observation:
        """One look at the counter; raises ``CameraFault`` when no attempt gave a usable frame."""
        attempts = self._limits.retries + 1
        for attempt in range(1, attempts + 1):
            try:
                return await self._look()
            except _BadFrame as e:
                log.debug("camera_frame_refused", attempt=attempt, of=attempts, reason=e.reason)
                if attempt == attempts:
                    log.warning("camera_failed", attempts=attempts, reason=e.reason)
                    raise CameraFault(f"camera: {e.reason}") from e
        raise AssertionError("unreachable")  # the loop returns or raises

    async def _look(self) -> Observation:
        frame = await self._capture()
        problem = frame_problem(frame)
        if problem is not None:
            raise _BadFrame(f"bad frame ({problem})")
        loop = asyncio.get_running_loop()
        started = time.perf_counter()
        try:
            detections: list[Detection] = await loop.run_in_executor(
                self._executor, self._detector.detect, frame
            )
        except FrameError as e:
            raise _BadFrame(f"bad frame ({e})") from e
        elapsed_ms = (time.perf_counter() - started) * 1000.0
        log.debug("mugs_detected", count=len(detections), detect_ms=round(elapsed_ms, 1))
        return Observation(
            t=frame.t,
            detections=tuple(detections),
            depth_preview=depth_preview(frame, width=self._preview_width),
            meta={**frame.meta, "detect_ms": f"{elapsed_ms:.1f}"},
        )

    async def _capture(self) -> RGBDFrame:
        """One frame within the timeout and the age limit, else ``_BadFrame`` saying which."""
        clock = self._clock
        try:
            if clock is None:
                frame = await self._camera.capture()
            else:
                async with clock.timeout(self._limits.timeout_s):
                    frame = await self._camera.capture()
        except TimeoutError as e:
            raise _BadFrame(f"no frame within {self._limits.timeout_s:.1f} s") from e
        except DriverError as e:  # the driver's own timeout or a lost device
            raise _BadFrame(str(e)) from e
        if clock is not None:
            age = clock.monotonic() - frame.t
            if age > self._limits.max_age_s:
                raise _BadFrame(f"frame {age:.1f} s old")
        return frame


class _BadFrame(Exception):
    """One attempt failed; ``reason`` says why (the observer retries, then raises ``CameraFault``)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def frame_problem(frame: RGBDFrame) -> str | None:
    """What makes a frame unusable as a depth image before any detection (None: nothing): a depth array
    that is not the intrinsics' image, depth that is not a number, a camera pose that is not a finite
    transform."""
    depth = np.asarray(frame.depth_m)
    K = frame.intrinsics
    if depth.ndim != 2:
        return f"depth image of shape {depth.shape}, expected {K.height}x{K.width} pixels"
    if depth.shape != (K.height, K.width):
        h, w = depth.shape
        return f"depth image is {w}x{h} pixels but the intrinsics say {K.width}x{K.height}"
    if not np.issubdtype(depth.dtype, np.floating):
        return f"depth of type {depth.dtype}, expected metres as floats"
    if np.isnan(depth).any():
        return "NaN depth"
    pose = np.asarray(frame.world_from_camera)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        return "camera pose is not a finite 4x4 transform"
    return None


def cell_observer_factory(
    cell: CellLayout,
    catalogue: Mapping[str, MugSpec],
    *,
    preview_width: int = 160,
    clock: Clock | None = None,
    limits: FrameLimits | None = None,
) -> Callable[[Camera], CameraObserver]:
    """Observers for the configured cell and mug catalogue: search the table, the tray included (the daemon
    loads the mugs on the counter and the flip area; on the tray it tells the mugs it placed from one that
    fell there). Frames are held to ``limits`` on ``clock``. The hardware and the MuJoCo cell both observe
    through it."""
    detector = DepthMugDetector(catalogue, region_m=cell.table_region_m)

    def factory(camera: Camera) -> CameraObserver:
        return CameraObserver(camera, detector, preview_width=preview_width, clock=clock, limits=limits)

    return factory


def depth_preview(frame: RGBDFrame, *, width: int = 160) -> npt.NDArray[np.float32]:
    """The depth image shrunk to ``width`` pixels across (metres; 0 = no reading), for monitoring.

    Nearest-neighbour sampling keeps "no reading" pixels at 0 instead of averaging them into fake depths.
    """
    h, w = frame.depth_m.shape
    height = max(1, round(h * width / w))
    small = cv2.resize(frame.depth_m.astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST)
    return np.ascontiguousarray(small, dtype=np.float32)
