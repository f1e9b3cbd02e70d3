"""CameraObserver: a MugObserver on the simulated depth camera, detection off the event loop."""

from __future__ import annotations

import asyncio
import threading

import mujoco
import numpy as np
import pytest

from description.cell import CellLayout, SceneMug
from description.thesis import BIG_MUG, MUG_TYPES, SMALL_MUG
from drivers.interfaces import RGBDFrame
from perception import CameraObserver, DepthMugDetector
from perception.errors import FrameError
from perception.interfaces import MugObserver
from sim.mujoco.camera import DepthCamera, DepthNoise
from sim.mujoco.scene import build_mjcf


class StillCamera:
    """A camera that always returns the same frame (the observer must not care where frames come from)."""

    def __init__(self, frame: RGBDFrame) -> None:
        self.frame = frame

    async def capture(self) -> RGBDFrame:
        return self.frame


def test_observer_on_the_simulated_camera_reports_the_mugs(layout: CellLayout) -> None:
    x0, y0, x1, y1 = layout.counter_region_m
    mugs = [
        SceneMug("a", BIG_MUG, x0 + 0.1, (y0 + y1) / 2),
        SceneMug("b", SMALL_MUG, x1 - 0.1, (y0 + y1) / 2),
    ]
    model = mujoco.MjModel.from_xml_string(build_mjcf(layout, mugs))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with DepthCamera(model, data, noise=DepthNoise(), seed=2) as camera:
        observer = CameraObserver(camera, DepthMugDetector(MUG_TYPES, region_m=layout.table_region_m))
        assert isinstance(observer, MugObserver)
        obs = asyncio.run(observer.observe())
    assert sorted(d.type for d in obs.detections) == ["big", "small"]
    assert obs.depth_preview is not None
    assert obs.depth_preview.shape == (120, 160)
    assert obs.depth_preview.dtype == np.float32
    assert float(obs.depth_preview.max()) > 0.5
    assert "detect_ms" in obs.meta


def test_detection_runs_off_the_event_loop_thread(layout: CellLayout) -> None:
    threads: list[str] = []

    class RecordingDetector(DepthMugDetector):
        def detect(self, frame: RGBDFrame) -> list:  # type: ignore[type-arg]
            threads.append(threading.current_thread().name)
            return []

    frame = RGBDFrame(0.0, np.ones((48, 64), np.float32), layout.camera.intrinsics(), np.eye(4))
    observer = CameraObserver(StillCamera(frame), RecordingDetector(MUG_TYPES))
    asyncio.run(observer.observe())
    assert len(threads) == 1
    assert threads[0] != threading.main_thread().name


def test_an_unusable_frame_raises_instead_of_reporting_an_empty_counter(layout: CellLayout) -> None:
    K = layout.camera.intrinsics()
    blank = RGBDFrame(0.0, np.zeros((K.height, K.width), np.float32), K, layout.camera.world_from_camera())
    observer = CameraObserver(StillCamera(blank))
    with pytest.raises(
        FrameError, match=r"^the depth image has only 0 valid pixels; is the camera covered\?$"
    ):
        asyncio.run(observer.observe())


def test_a_tiny_preview_is_refused() -> None:
    frame = RGBDFrame(0.0, np.ones((4, 4), np.float32), None, np.eye(4))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^preview_width 4: use at least 8 pixels$"):
        CameraObserver(StillCamera(frame), preview_width=4)


def test_cell_observer_leaves_out_the_mugs_already_in_the_tray(layout: CellLayout) -> None:
    from perception.observer import cell_observer_factory
    from tests.perception.scenes import render

    x0, y0, x1, y1 = layout.tray.region_m
    cx0, cy0, cx1, cy1 = layout.counter_region_m
    placed = SceneMug("placed", SMALL_MUG, (x0 + x1) / 2, (y0 + y1) / 2)
    waiting = SceneMug("waiting", BIG_MUG, (cx0 + cx1) / 2, (cy0 + cy1) / 2)
    frame = render(layout, [placed, waiting], noise=DepthNoise(), seed=6)
    observer = cell_observer_factory(layout, MUG_TYPES)(StillCamera(frame))
    obs = asyncio.run(observer.observe())
    assert [(d.type, round(d.x_m, 2), round(d.y_m, 2)) for d in obs.detections] == [
        ("big", round(waiting.x_m, 2), round(waiting.y_m, 2))
    ]
