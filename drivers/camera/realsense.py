"""An Intel RealSense depth camera (D400 series) as a ``drivers.interfaces.Camera``.

pyrealsense2 is an optional extra (``pip install 'dishbot[realsense]'``); without it, :meth:`start` raises
:class:`CameraUnavailable` saying so, and nothing else in dishbot needs it. Depth is aligned to the colour
image so a pixel means the same point in both; intrinsics are those of the aligned stream.
"""

from __future__ import annotations

import asyncio
import importlib
from types import ModuleType, TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt
import structlog

from drivers.errors import DriverError
from drivers.interfaces import CameraIntrinsics, Clock, FloatArray, RGBDFrame

log = structlog.get_logger("drivers.camera")


class CameraUnavailable(DriverError):
    """The camera package is missing or no camera is connected."""


def load_pyrealsense() -> ModuleType:
    """The pyrealsense2 module, or CameraUnavailable naming the extra that provides it."""
    try:
        return importlib.import_module("pyrealsense2")
    except ImportError as e:
        raise CameraUnavailable(
            "pyrealsense2 is not installed; install the optional extra with "
            "`pip install 'dishbot[realsense]'`"
        ) from e


def depth_in_metres(raw: npt.NDArray[np.uint16], depth_scale_m: float) -> npt.NDArray[np.float32]:
    """Z16 depth units to metres (0 stays 0 = no reading)."""
    return (raw.astype(np.float32) * np.float32(depth_scale_m)).astype(np.float32)


class RealSenseCamera:
    """Streams aligned depth + colour from the first (or the named) RealSense camera."""

    def __init__(
        self,
        *,
        world_from_camera: FloatArray,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        serial_number: str | None = None,
        with_color: bool = True,
        timeout_s: float = 1.0,
        clock: Clock,
    ) -> None:
        if np.asarray(world_from_camera).shape != (4, 4):
            raise ValueError("camera.world_from_camera must be a 4x4 homogeneous transform")
        self.world_from_camera = np.asarray(world_from_camera, dtype=np.float64)
        self.width, self.height, self.fps = width, height, fps
        self.serial_number = serial_number
        self.with_color = with_color
        self.timeout_s = timeout_s
        self._clock = clock
        self._rs: Any = None
        self._pipeline: Any = None
        self._align: Any = None
        self._scale = 0.001
        self._intrinsics: CameraIntrinsics | None = None

    async def start(self) -> None:
        self._rs = load_pyrealsense()
        await asyncio.to_thread(self._start_blocking)

    def _start_blocking(self) -> None:
        rs = self._rs
        config = rs.config()
        if self.serial_number:
            config.enable_device(self.serial_number)
        config.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
        if self.with_color:
            config.enable_stream(rs.stream.color, self.width, self.height, rs.format.rgb8, self.fps)
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(config)
        except RuntimeError as e:
            which = f"serial {self.serial_number}" if self.serial_number else "any serial"
            raise CameraUnavailable(
                f"no RealSense camera ({which}) could stream: {e}; check the USB 3 cable"
            ) from e
        self._pipeline = pipeline
        self._scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        self._align = rs.align(rs.stream.color) if self.with_color else None
        stream = rs.stream.color if self.with_color else rs.stream.depth
        intr = profile.get_stream(stream).as_video_stream_profile().get_intrinsics()
        self._intrinsics = CameraIntrinsics(intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy)
        log.info("camera_started", depth_scale_m=self._scale, width=intr.width, height=intr.height)

    async def stop(self) -> None:
        pipeline, self._pipeline = self._pipeline, None
        if pipeline is not None:
            await asyncio.to_thread(pipeline.stop)

    async def __aenter__(self) -> RealSenseCamera:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.stop()

    async def capture(self) -> RGBDFrame:
        if self._pipeline is None or self._intrinsics is None:
            raise CameraUnavailable(
                "the RealSense camera is not started; use `async with RealSenseCamera(...)`"
            )
        return await asyncio.to_thread(self._capture_blocking)

    def _capture_blocking(self) -> RGBDFrame:
        try:
            frames = self._pipeline.wait_for_frames(int(self.timeout_s * 1000))
        except RuntimeError as e:
            raise CameraUnavailable(
                f"the RealSense camera sent no frame within {self.timeout_s:.1f} s: {e}"
            ) from e
        if self._align is not None:
            frames = self._align.process(frames)
        depth_frame = frames.get_depth_frame()
        depth = depth_in_metres(np.asanyarray(depth_frame.get_data()), self._scale)
        color = None
        if self.with_color:
            color = np.ascontiguousarray(np.asanyarray(frames.get_color_frame().get_data()), dtype=np.uint8)
        assert self._intrinsics is not None
        return RGBDFrame(
            t=self._clock.monotonic(),
            depth_m=depth,
            intrinsics=self._intrinsics,
            world_from_camera=self.world_from_camera.copy(),
            color=color,
            meta={"source": "realsense", "frame_number": str(depth_frame.get_frame_number())},
        )
