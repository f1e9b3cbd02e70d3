"""A depth camera on another process or computer: its frames arrive as Zenoh samples (``[hardware] camera =
"zenoh"``).

A camera node (``dishbot sim rig``, or a node driving a real camera on a second computer) publishes depth
frames on a key in the ``wire.depth`` format; this driver subscribes over its own Zenoh session, connected to
the node's endpoint, and hands the job the next frame that arrives after each ``capture()``, stamped on the
daemon's clock when it arrived (as a USB camera's frames are stamped by the host). The intrinsics and the pose
are the configured camera's (``[camera]`` or its calibration file), exactly as for a RealSense; a frame of
another size is refused by the observer's frame checks. A node that stops publishing shows as frames that do
not come: the observer's frame timeout and retries turn that into a camera fault.

The subscriber's callback runs on a Zenoh thread: it copies the sample's bytes and hands them to the event
loop with ``call_soon_threadsafe``; decoding happens in ``capture()``.
"""

from __future__ import annotations

import asyncio
import contextlib
from types import TracebackType

import numpy as np
import structlog
import zenoh

from daemon.zenoh_session import error_text, session_config
from drivers.errors import SensorFault
from drivers.interfaces import CameraIntrinsics, Clock, FloatArray, RGBDFrame
from wire.depth import BadFrame, decode_depth

log = structlog.get_logger("daemon.zenoh_camera")


class CameraUnreachable(ConnectionError):
    """The camera's Zenoh session could not be opened (a malformed endpoint, an address in use)."""


class ZenohCamera:
    """Depth frames from a camera node on ``key``, reached at ``connect``; ``async with`` opens, closes."""

    def __init__(
        self,
        *,
        connect: str,
        key: str,
        intrinsics: CameraIntrinsics,
        world_from_camera: FloatArray,
        clock: Clock,
    ) -> None:
        if np.asarray(world_from_camera).shape != (4, 4):
            raise ValueError("camera world_from_camera must be a 4x4 homogeneous transform")
        self.connect = connect
        self.key = key
        self.intrinsics = intrinsics
        self.world_from_camera = np.asarray(world_from_camera, dtype=np.float64)
        self._clock = clock
        self._session: zenoh.Session | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._latest: tuple[float, bytes, bytes | None] | None = None
        self._waiters: list[asyncio.Future[None]] = []
        self.frames_received = 0

    async def __aenter__(self) -> ZenohCamera:
        self._loop = asyncio.get_running_loop()
        config = session_config(listen=(), connect=(self.connect,))
        try:
            self._session = await asyncio.to_thread(zenoh.open, config)
        except zenoh.ZError as e:
            reason = error_text(e)
            raise CameraUnreachable(f"camera: cannot open a Zenoh session to {self.connect}: {reason}") from e
        self._session.declare_subscriber(self.key, self._on_sample)
        log.info("camera_started", source="zenoh", connect=self.connect, key=self.key)
        return self

    async def __aexit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        session, self._session = self._session, None
        for waiter in self._waiters:
            waiter.cancel()
        if session is not None:
            with contextlib.suppress(zenoh.ZError):
                await asyncio.to_thread(session.close)

    def _on_sample(self, sample: zenoh.Sample) -> None:  # on a Zenoh thread: copy, hand over, return
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        attachment = sample.attachment
        data = (sample.payload.to_bytes(), attachment.to_bytes() if attachment is not None else None)
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            loop.call_soon_threadsafe(self._arrived, *data)

    def _arrived(self, payload: bytes, attachment: bytes | None) -> None:
        self._latest = (self._clock.monotonic(), payload, attachment)
        self.frames_received += 1
        waiters, self._waiters = self._waiters, []
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(None)

    async def capture(self) -> RGBDFrame:
        """The first frame that arrives after the call (a fresh one, never an old one again)."""
        if self._session is None:
            raise SensorFault(f"camera on {self.connect}: not open")
        waiter = asyncio.get_running_loop().create_future()
        self._waiters.append(waiter)
        await waiter
        if self._latest is None:  # woken only once a frame is in; never None here
            raise SensorFault(f"camera on {self.connect}: woken without a frame")
        t, payload, attachment = self._latest
        try:
            header, depth = decode_depth(payload, attachment)
        except BadFrame as e:
            raise SensorFault(f"camera on {self.connect} ({self.key}): {e}") from e
        return RGBDFrame(
            t=t,
            depth_m=depth,
            intrinsics=self.intrinsics,
            world_from_camera=self.world_from_camera,
            meta={"source": "zenoh", "key": self.key, "seq": str(header.seq)},
        )
