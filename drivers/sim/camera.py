"""A depth camera that can fail the ways a real one does: a ``drivers.interfaces.Camera`` around another.

The simulated cell's rendered camera never fails; a RealSense does. ``FaultyCamera`` passes frames through
until a fault is set, then:

- ``no_frame``: the capture waits the driver's frame timeout on the clock and raises ``CameraUnavailable``
  with the RealSense driver's message (``drivers.camera.realsense``);
- ``stale``: the last frame comes back again, with its old ``t``;
- ``bad_frame``: a frame whose depth is all NaN (a covered or failing sensor);
- ``hang``: the capture does not return until the fault is cleared (a wedged USB pipeline).

Clearing the fault (``clear()``) lets a hung capture finish with a fresh frame.
"""

from __future__ import annotations

import asyncio
import dataclasses
from typing import Final, Literal

import numpy as np

from drivers.camera.realsense import CameraUnavailable
from drivers.interfaces import Camera, Clock, RGBDFrame

CameraFaultKind = Literal["no_frame", "stale", "bad_frame", "hang"]
CAMERA_FAULTS: Final[tuple[CameraFaultKind, ...]] = ("no_frame", "stale", "bad_frame", "hang")


class FaultyCamera:
    """``camera`` with an injectable fault; ``timeout_s`` is how long a capture waits before "no frame"
    (the RealSense driver's default)."""

    def __init__(self, camera: Camera, *, clock: Clock, timeout_s: float = 1.0) -> None:
        self._camera = camera
        self._clock = clock
        self.timeout_s = timeout_s
        self.fault: CameraFaultKind | None = None
        self._last: RGBDFrame | None = None
        self._cleared: asyncio.Event | None = None
        self.faulty_captures = 0  # captures a fault changed (for tests and the replay's report)

    def set_fault(self, fault: CameraFaultKind) -> None:
        """Fail every capture from now on in the ``fault`` way, until :meth:`clear`."""
        if fault not in CAMERA_FAULTS:
            raise ValueError(f"camera fault {fault!r}: choose one of {', '.join(CAMERA_FAULTS)}")
        self.fault = fault

    def clear(self) -> None:
        """Work again (a hung capture returns a fresh frame)."""
        self.fault = None
        if self._cleared is not None:
            self._cleared.set()
            self._cleared = None

    async def capture(self) -> RGBDFrame:
        fault = self.fault
        if fault == "hang":
            self.faulty_captures += 1
            while self.fault == "hang":
                if self._cleared is None:
                    self._cleared = asyncio.Event()
                await self._cleared.wait()
        elif fault == "no_frame":
            self.faulty_captures += 1
            await self._clock.sleep(self.timeout_s)
            raise CameraUnavailable(
                f"the RealSense camera sent no frame within {self.timeout_s:.1f} s: Frame didn't arrive "
                f"within {round(self.timeout_s * 1000)}"
            )
        elif fault == "stale" and self._last is not None:
            self.faulty_captures += 1
            return self._last
        frame = await self._camera.capture()
        if fault == "bad_frame":
            self.faulty_captures += 1
            return dataclasses.replace(frame, depth_m=np.full_like(frame.depth_m, np.nan))
        self._last = frame
        return frame
