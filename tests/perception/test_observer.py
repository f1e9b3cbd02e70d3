"""CameraObserver: a MugObserver on the simulated depth camera, detection off the event loop."""

from __future__ import annotations

import asyncio
import math
import threading

import mujoco
import numpy as np
import pytest

from description.cell import CellLayout, SceneMug
from description.thesis import BIG_MUG, MUG_TYPES, SMALL_MUG
from drivers.interfaces import RGBDFrame
from perception import CameraObserver, DepthMugDetector
from perception.errors import CameraFault, FrameError
from perception.interfaces import MugObserver, Observation
from perception.observer import FrameLimits
from sim.mujoco.camera import DepthCamera, DepthNoise
from sim.mujoco.scene import build_mjcf
from tests.fakes.devices import ScriptedCamera


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

    K = layout.camera.intrinsics()
    frame = RGBDFrame(0.0, np.ones((K.height, K.width), np.float32), K, np.eye(4))
    observer = CameraObserver(StillCamera(frame), RecordingDetector(MUG_TYPES))
    asyncio.run(observer.observe())
    assert len(threads) == 1
    assert threads[0] != threading.main_thread().name


def test_an_unusable_frame_is_a_camera_fault_instead_of_an_empty_counter(layout: CellLayout) -> None:
    K = layout.camera.intrinsics()
    blank = RGBDFrame(0.0, np.zeros((K.height, K.width), np.float32), K, layout.camera.world_from_camera())
    observer = CameraObserver(StillCamera(blank))
    with pytest.raises(
        CameraFault,
        match=r"^camera: bad frame \(the depth image has only 0 valid pixels; is the camera covered\?\)$",
    ) as caught:
        asyncio.run(observer.observe())
    assert isinstance(caught.value.__cause__.__cause__, FrameError)  # type: ignore[union-attr]


@pytest.fixture(scope="module")
def counter_frame(layout: CellLayout) -> RGBDFrame:
    """The cell with a big and a small mug on the counter, as the configured camera sees it."""
    from tests.perception.scenes import render

    x0, y0, x1, y1 = layout.counter_region_m
    mugs = [
        SceneMug("a", BIG_MUG, x0 + 0.1, (y0 + y1) / 2),
        SceneMug("b", SMALL_MUG, x1 - 0.1, (y0 + y1) / 2),
    ]
    return render(layout, mugs, noise=DepthNoise(), seed=3)


def _observe_on_simulated_time(
    layout: CellLayout, frame: RGBDFrame, script: list[str], *, then: str = "ok"
) -> tuple[Observation | CameraFault, list[str], float]:
    """What observing through a scripted camera gives (the observation or the fault), the captures, and the
    simulated time it took."""
    from daemon.clock import SimulatedClock
    from perception.observer import cell_observer_factory

    clock = SimulatedClock()
    camera = ScriptedCamera(frame, clock, script, then=then)
    observer = cell_observer_factory(layout, MUG_TYPES, clock=clock, limits=FrameLimits(2.0, 1.0, 2))(camera)

    async def go() -> tuple[Observation | CameraFault, float]:
        started = clock.monotonic()
        try:
            result: Observation | CameraFault = await observer.observe()
        except CameraFault as e:
            result = e
        return result, clock.monotonic() - started

    result, took = clock.run(go())
    return result, camera.captures, took


@pytest.mark.parametrize(
    ("fault", "reason", "took_s"),
    [
        ("hang", "camera: no frame within 2.0 s", 6.0),
        ("stale", "camera: frame 600.0 s old", 0.0),
        ("nan", "camera: bad frame (NaN depth)", 0.0),
        ("shape", "camera: bad frame (depth image is 320x240 pixels but the intrinsics say 640x480)", 0.0),
    ],
)
def test_a_failing_camera_is_tried_three_times_then_a_camera_fault_with_the_reason(
    layout: CellLayout, counter_frame: RGBDFrame, fault: str, reason: str, took_s: float
) -> None:
    result, captures, took = _observe_on_simulated_time(layout, counter_frame, [], then=fault)
    assert isinstance(result, CameraFault)
    assert str(result) == reason
    assert captures == [fault] * 3
    assert took == pytest.approx(took_s)


def test_a_camera_that_fails_less_often_than_the_retries_still_sees_the_mugs(
    layout: CellLayout, counter_frame: RGBDFrame
) -> None:
    result, captures, took = _observe_on_simulated_time(layout, counter_frame, ["hang", "nan"])
    assert isinstance(result, Observation)
    assert sorted(d.type for d in result.detections) == ["big", "small"]
    assert captures == ["hang", "nan", "ok"]
    assert took == pytest.approx(2.0)


def test_frame_limits_are_checked() -> None:
    with pytest.raises(ValueError, match=r"^frame timeout_s 0.0: must be positive$"):
        FrameLimits(timeout_s=0.0)
    with pytest.raises(ValueError, match=r"^frame retries -1: must be 0 or more$"):
        FrameLimits(retries=-1)


def test_a_tiny_preview_is_refused() -> None:
    frame = RGBDFrame(0.0, np.ones((4, 4), np.float32), None, np.eye(4))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^preview_width 4: use at least 8 pixels$"):
        CameraObserver(StillCamera(frame), preview_width=4)


def test_cell_observer_sees_the_mugs_on_the_counter_and_on_the_tray(layout: CellLayout) -> None:
    """The daemon tells the mugs it placed from one that fell onto the tray (``daemon.job.counter``), so the
    observer reports both; the tray's walls are no mug."""
    from perception.observer import cell_observer_factory
    from tests.perception.scenes import render

    x0, y0, x1, y1 = layout.tray.region_m
    cx0, cy0, cx1, cy1 = layout.counter_region_m
    placed = SceneMug("placed", SMALL_MUG, (x0 + x1) / 2, (y0 + y1) / 2)
    waiting = SceneMug("waiting", BIG_MUG, (cx0 + cx1) / 2, (cy0 + cy1) / 2)
    frame = render(layout, [placed, waiting], noise=DepthNoise(), seed=6)
    observer = cell_observer_factory(layout, MUG_TYPES)(StillCamera(frame))
    obs = asyncio.run(observer.observe())
    seen = sorted((d.type, d.x_m, d.y_m) for d in obs.detections)
    assert [t for t, _, _ in seen] == ["big", "small"]
    for (_, x, y), mug in zip(seen, (waiting, placed), strict=True):
        assert math.hypot(x - mug.x_m, y - mug.y_m) < 0.01
