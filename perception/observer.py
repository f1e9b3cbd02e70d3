"""The daemon's eyes: capture a depth frame, detect the mugs off the event loop, keep a small preview."""

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
from drivers.interfaces import Camera, RGBDFrame
from perception.detector import DepthMugDetector
from perception.interfaces import Detection, Observation

log = structlog.get_logger(__name__)


class CameraObserver:
    """Implements ``perception.interfaces.MugObserver`` on a depth camera and the depth mug detector.

    Detection (tens of milliseconds of numpy) runs in ``executor`` (the loop's default thread pool when None)
    so the event loop keeps publishing telemetry meanwhile. The capture itself is awaited on the loop: a
    simulated camera renders on the thread that owns its GL context. Without a detector, one for the
    thesis's two mug types searches the whole table in view.
    """

    def __init__(
        self,
        camera: Camera,
        detector: DepthMugDetector | None = None,
        *,
        preview_width: int = 160,
        executor: Executor | None = None,
    ) -> None:
        if preview_width < 8:
            raise ValueError(f"preview_width {preview_width}: use at least 8 pixels")
        self._camera = camera
        self._detector = detector or DepthMugDetector(MUG_TYPES)
        self._preview_width = preview_width
        self._executor = executor

    @property
    def detector(self) -> DepthMugDetector:
        """The detector the observer runs on each frame (its catalogue, region and exclusions)."""
        return self._detector

    async def observe(self) -> Observation:
        """One look at the counter; raises ``perception.errors.FrameError`` when the frame is unusable."""
        frame = await self._camera.capture()
        loop = asyncio.get_running_loop()
        started = time.perf_counter()
        detections: list[Detection] = await loop.run_in_executor(self._executor, self._detector.detect, frame)
        elapsed_ms = (time.perf_counter() - started) * 1000.0
        log.debug("mugs_detected", count=len(detections), detect_ms=round(elapsed_ms, 1))
        return Observation(
            t=frame.t,
            detections=tuple(detections),
            depth_preview=depth_preview(frame, width=self._preview_width),
            meta={**frame.meta, "detect_ms": f"{elapsed_ms:.1f}"},
        )


def cell_observer_factory(
    cell: CellLayout, catalogue: Mapping[str, MugSpec], *, preview_width: int = 160
) -> Callable[[Camera], CameraObserver]:
    """Observers for the configured cell and mug catalogue: search the table, and leave out the mugs standing
    in the tray (they are placed; the daemon looks for the mugs still to load, on the counter and the flip
    area). The hardware and the MuJoCo cell both observe through it."""
    detector = DepthMugDetector(
        catalogue, region_m=cell.table_region_m, exclude_m=(cell.tray.outer_region_m,)
    )

    def factory(camera: Camera) -> CameraObserver:
        return CameraObserver(camera, detector, preview_width=preview_width)

    return factory


def depth_preview(frame: RGBDFrame, *, width: int = 160) -> npt.NDArray[np.float32]:
    """The depth image shrunk to ``width`` pixels across (metres; 0 = no reading), for monitoring.

    Nearest-neighbour sampling keeps "no reading" pixels at 0 instead of averaging them into fake depths.
    """
    h, w = frame.depth_m.shape
    height = max(1, round(h * width / w))
    small = cv2.resize(frame.depth_m.astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST)
    return np.ascontiguousarray(small, dtype=np.float32)
