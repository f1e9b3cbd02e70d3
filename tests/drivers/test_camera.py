"""The RealSense camera: skipped cleanly without pyrealsense2, clear error when it is missing."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from daemon.clock import RealClock
from drivers.camera import CameraUnavailable, RealSenseCamera, depth_in_metres, load_pyrealsense
from drivers.interfaces import Camera
from tests.fakes.devices import async_test


def test_realsense_camera_implements_the_camera_protocol() -> None:
    assert isinstance(RealSenseCamera(world_from_camera=np.eye(4), clock=RealClock()), Camera)


def test_missing_pyrealsense_gives_an_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    with pytest.raises(CameraUnavailable) as raised:
        load_pyrealsense()
    assert str(raised.value) == (
        "pyrealsense2 is not installed; install the optional extra with `pip install 'dishbot[realsense]'`"
    )


def test_z16_depth_becomes_metres_and_zero_stays_no_reading() -> None:
    raw = np.array([[0, 1000], [65535, 250]], dtype=np.uint16)
    metres = depth_in_metres(raw, 0.001)
    assert metres.dtype == np.float32
    np.testing.assert_allclose(metres, [[0.0, 1.0], [65.535, 0.25]], rtol=1e-6)


def test_a_bad_camera_pose_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"^camera\.world_from_camera must be a 4x4 homogeneous transform$"):
        RealSenseCamera(world_from_camera=np.eye(3), clock=RealClock())


@async_test
async def test_a_connected_realsense_streams_a_frame() -> None:
    rs = pytest.importorskip("pyrealsense2")
    if not rs.context().query_devices():
        pytest.skip("no RealSense camera connected")
    async with RealSenseCamera(world_from_camera=np.eye(4), clock=RealClock()) as camera:
        frame = await camera.capture()
    assert frame.depth_m.shape == (frame.intrinsics.height, frame.intrinsics.width)
