"""The ``zenoh`` camera: depth frames a camera node publishes reach the job as frames of the configured
camera, over real Zenoh sessions on loopback (multicast scouting off, explicit endpoints)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Iterator

import numpy as np
import pytest
import zenoh

from daemon.clock import RealClock
from daemon.config import load_config
from daemon.errors import ConfigError
from daemon.zenoh_camera import ZenohCamera
from daemon.zenoh_session import session_config
from drivers.errors import SensorFault
from drivers.interfaces import CameraIntrinsics
from tests.daemon.conftest import free_port
from wire.depth import encode_depth

KEY = "test/camera/depth"
K = CameraIntrinsics(4, 3, 3.0, 3.0, 2.0, 1.5)
# A guard against a hang, not a measurement: frames cross loopback in milliseconds.
GUARD_S = 20.0


@pytest.fixture
def node() -> Iterator[tuple[str, zenoh.Session]]:
    """A camera node's session listening on a free loopback port."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(session_config(listen=(endpoint,), connect=()))
    try:
        yield endpoint, session
    finally:
        session.close()  # type: ignore[no-untyped-call]


@contextlib.asynccontextmanager
async def opened(endpoint: str) -> AsyncIterator[ZenohCamera]:
    async with ZenohCamera(
        connect=endpoint, key=KEY, intrinsics=K, world_from_camera=np.eye(4), clock=RealClock()
    ) as camera:
        yield camera


async def publish_until_captured(
    session: zenoh.Session, capture: asyncio.Task[object], frames: list[bytes]
) -> None:
    """Publish until the capture returns (the subscriber may join a moment after the first put)."""
    publisher = session.declare_publisher(KEY)
    seq = 0
    while not capture.done():
        payload = frames[min(seq, len(frames) - 1)]
        depth = np.frombuffer(payload, dtype=np.float32).reshape(3, 4)
        payload, attachment = encode_depth(depth, seq=seq, t=1e9 + seq)
        publisher.put(payload, attachment=attachment)
        seq += 1
        await asyncio.sleep(0.02)


def test_a_published_frame_is_captured_with_the_configured_camera(node: tuple[str, zenoh.Session]) -> None:
    endpoint, session = node
    depth = np.arange(12, dtype=np.float32).reshape(3, 4) / 10.0

    async def scenario() -> None:
        async with opened(endpoint) as camera:
            capture = asyncio.ensure_future(camera.capture())
            await asyncio.wait_for(publish_until_captured(session, capture, [depth.tobytes()]), GUARD_S)
            frame = capture.result()
            assert frame.intrinsics == K
            assert np.allclose(frame.depth_m, depth, atol=0.0006)
            assert frame.meta["source"] == "zenoh"
            assert abs(frame.t - RealClock().monotonic()) < GUARD_S  # stamped on the daemon's clock
            assert camera.frames_received >= 1

    asyncio.run(scenario())


def test_capture_waits_for_a_frame_newer_than_the_call(node: tuple[str, zenoh.Session]) -> None:
    endpoint, session = node
    old, new = np.zeros((3, 4), np.float32), np.full((3, 4), 0.7, np.float32)

    async def scenario() -> None:
        async with opened(endpoint) as camera:
            first = asyncio.ensure_future(camera.capture())
            await asyncio.wait_for(publish_until_captured(session, first, [old.tobytes()]), GUARD_S)
            # The old frame is in; a new capture must not return it again but wait for the next one.
            second = asyncio.ensure_future(camera.capture())
            await asyncio.sleep(0)
            assert not second.done()
            payload, attachment = encode_depth(new, seq=99, t=2e9)
            session.put(KEY, payload, attachment=attachment)
            frame = await asyncio.wait_for(second, GUARD_S)
            assert frame.meta["seq"] == "99"
            assert np.allclose(frame.depth_m, 0.7)

    asyncio.run(scenario())


def test_a_sample_that_is_not_a_frame_is_a_sensor_fault(node: tuple[str, zenoh.Session]) -> None:
    endpoint, session = node

    async def scenario() -> None:
        async with opened(endpoint) as camera:
            capture = asyncio.ensure_future(camera.capture())
            publisher = session.declare_publisher(KEY)
            while not capture.done():
                publisher.put(b"\0\0", attachment=b'{"encoding":"uint16_mm_le","width":4,"height":3}')
                await asyncio.sleep(0.02)
            with pytest.raises(SensorFault) as err:
                capture.result()
            assert str(err.value) == (
                f"camera on {endpoint} ({KEY}): frame has 2 bytes for 4x3 pixels (expected 24)"
            )

    asyncio.run(scenario())


def test_the_config_takes_a_zenoh_camera_and_checks_its_endpoint_and_key() -> None:
    config = load_config(overrides={"hardware": {"camera": "zenoh", "zenoh_camera": {"key": "cam/depth"}}})
    assert config.hardware.camera == "zenoh"
    assert config.hardware.zenoh_camera.key == "cam/depth"
    with pytest.raises(ConfigError) as err:
        load_config(overrides={"hardware": {"zenoh_camera": {"connect": "localhost"}}})
    assert str(err.value).startswith("hardware.zenoh_camera.connect: 'localhost' is not a Zenoh endpoint")
    with pytest.raises(ConfigError) as err:
        load_config(overrides={"hardware": {"zenoh_camera": {"key": "cam/**"}}})
    assert str(err.value) == "hardware.zenoh_camera.key: 'cam/**' is not a plain Zenoh key (no wildcards)"
    with pytest.raises(ConfigError) as err:
        load_config(overrides={"hardware": {"camera": "usb"}})
    assert str(err.value) == "hardware.camera: 'usb' is not one of realsense, zenoh, none"
