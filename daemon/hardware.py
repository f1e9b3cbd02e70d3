"""The robot's backend: the device stack of ``[hardware]`` on its serial ports, the camera with the depth
detector and the cycle planner, assembled from the config; and the Foxglove scene of the configured cell.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import structlog

from daemon.backend import Backend, DeviceEvents
from daemon.clock import RealClock, SessionClock
from daemon.config import Config
from daemon.errors import UsageError
from daemon.planners import cycle_planner
from drivers.dynamixel import BusConfig
from drivers.errors import BusLost, DriverError
from drivers.interfaces import (
    Camera,
)
from drivers.serial_port import OpenSerial
from drivers.stack import (
    ARM_JOINTS,
    StackSpec,
    arm_joints,
    gripper_spec,
    open_device_stack,
)
from perception.interfaces import MugObserver, Observation
from planning.arm import ArmModel

if TYPE_CHECKING:
    from perception.calibration import CameraModel
    from recorder.foxglove_scene import SceneView

log = structlog.get_logger("daemon.backend")
T = TypeVar("T")


def hardware_stack_spec(config: Config, arm: ArmModel) -> StackSpec:
    """The device stack of ``[hardware]``: each joint's servo with the URDF's limits, the gripper (its
    measured aperture map, or the arm model's gripper geometry when none is given), the FSR and the bus."""
    hw = config.hardware
    try:
        joints = arm_joints([(j, hw.servo(j).id, hw.servo(j).model) for j in ARM_JOINTS])
        grip = hw.servo("gripper")
        gripper = dataclasses.replace(
            gripper_spec(arm.gripper, servo_id=grip.id),
            model=grip.model,
            grip_limit=hw.gripper.grip_limit,
            grip_limit_backoff=hw.gripper.grip_limit_backoff,
            overload_retries=hw.gripper.overload_retries,
        )
        if hw.gripper.aperture_map:
            apertures = [m for _, m in hw.gripper.aperture_map]
            gripper = dataclasses.replace(
                gripper, aperture_map=hw.gripper.aperture_map, open_aperture_m=max(apertures)
            )
        return StackSpec(
            bus=BusConfig(hw.servo_port, hw.baudrate, 1 if hw.protocol == 1 else 2),
            joints=joints,
            gripper=gripper,
            fsr=hw.fsr,
            retries=hw.retries,
            read_timeout_s=hw.read_timeout_s,
            health=hw.health,
        )
    except ValueError as e:
        raise UsageError(f"hardware: {e}") from e


class _NoCamera:
    """``hardware.camera = "none"``: the devices run (telemetry, faults, commands) but the counter looks
    empty, so a started job ends done at once."""

    def __init__(self, clock: SessionClock) -> None:
        self._clock = clock

    async def observe(self) -> Observation:
        return Observation(t=self._clock.monotonic(), detections=(), meta={"source": "none"})


async def open_hardware_backend(
    config: Config,
    *,
    arm: ArmModel | None = None,
    executor: concurrent.futures.Executor | None = None,
    camera: Camera | None = None,
    clock: SessionClock | None = None,
    open_bus: OpenSerial | None = None,
    open_fsr: OpenSerial | None = None,
) -> Backend:
    """The robot: the device stack of ``[hardware]`` on its serial ports (the same stack the MuJoCo cell
    builds over its simulators) and the RealSense camera with the depth detector, on the wall clock
    (``clock``, default a ``RealClock``). ``camera`` replaces the configured camera (a stand-in for tests);
    ``open_bus`` and ``open_fsr`` open the ports instead of pyserial (the in-process simulators' cables,
    for tests on a simulated clock). A missing port, a missing pyrealsense2 or a servo chain that does not
    match the config is a one-line ``UsageError``. Call it on the event loop that will use the devices."""
    clock = clock or RealClock()
    hw = config.hardware
    ports = (("hardware.servo_port", hw.servo_port, open_bus), ("hardware.fsr.port", hw.fsr.port, open_fsr))
    for key, port, opener in ports:
        if opener is None and not Path(port).exists():  # noqa: ASYNC240 (one stat at start-up)
            raise UsageError(
                f"{key}: {port} does not exist; plug the adapter in and install the udev rule "
                "(docs/hardware.md), or set the port"
            )
    if camera is None and hw.camera == "realsense":
        from drivers.camera import CameraUnavailable, load_pyrealsense

        try:
            load_pyrealsense()
        except CameraUnavailable as e:
            raise UsageError(f"hardware.camera: {e}") from e
    arm_model = arm or ArmModel.load()
    spec = dataclasses.replace(hardware_stack_spec(config, arm_model), open_bus=open_bus, open_fsr=open_fsr)
    motion = cycle_planner(config, config.cell.tray, arm=arm_model, executor=executor)
    events = DeviceEvents(clock)
    stack = contextlib.AsyncExitStack()
    try:
        devices = await open_device_stack(spec, stack, clock=clock, on_event=events)
        observer = await _hardware_observer(config, stack, camera, clock)
    except BaseException as e:
        await stack.aclose()
        if isinstance(e, DriverError | BusLost):
            raise UsageError(f"cannot open the robot's devices: {e}") from e
        raise

    async def close() -> None:
        """Torque off and close the ports; a device that is already gone (unplugged, faulted) cannot be
        switched off and is only logged, so the daemon still exits cleanly."""
        try:
            await stack.aclose()
        except (DriverError, BusLost) as e:
            log.warning("device_close_failed", error=str(e))

    return Backend(
        name="hardware",
        arm=devices.arm,
        gripper=devices.gripper,
        force=devices.force,
        observer=observer,
        motion=motion,
        tray=config.cell.tray,
        closer=close,
        on_event=events.add,
        devices=devices,
        health=devices.health,
        clock=clock,
    )


def configured_camera_model(config: Config) -> CameraModel:
    """The camera as the config describes it: ``[camera]``'s image and pose, or its calibration file;
    ``ValueError`` (``CalibrationError``) naming what is wrong."""
    from perception.calibration import camera_model

    c = config.cell.camera
    return camera_model(
        width=c.width,
        height=c.height,
        fovy_deg=c.fovy_deg,
        position_m=c.position_m,
        yaw_rad=c.yaw_rad,
        pitch_rad=c.pitch_rad,
        calibration_file=config.camera.calibration_file,
    )


def scene_view(config: Config, *, depth_hz: float = 1.0) -> SceneView:
    """The Foxglove scene of the configured cell; without the camera (logged) when its model is unknown."""
    from perception.errors import CalibrationError
    from recorder.foxglove_scene import SceneView

    camera: CameraModel | None
    try:
        camera = configured_camera_model(config)
    except (CalibrationError, ValueError) as e:
        log.warning("foxglove_camera_unknown", error=str(e))
        camera = None
    return SceneView(config.mug_types, config.cell, camera=camera, depth_hz=depth_hz)


async def _hardware_observer(
    config: Config, stack: contextlib.AsyncExitStack, camera: Camera | None, clock: SessionClock
) -> MugObserver:
    """The mug observer on the configured camera: depth detection over the table, the tray left out."""
    from drivers.camera import RealSenseCamera
    from perception.observer import cell_observer_factory

    if camera is None and config.hardware.camera == "none":
        return _NoCamera(clock)
    try:
        model = configured_camera_model(config)
    except ValueError as e:
        raise UsageError(f"camera: {e}") from e
    if camera is None and config.hardware.camera == "zenoh":
        from daemon.zenoh_camera import CameraUnreachable, ZenohCamera

        source = config.hardware.zenoh_camera
        try:
            camera = await stack.enter_async_context(
                ZenohCamera(
                    connect=source.connect,
                    key=source.key,
                    intrinsics=model.intrinsics,
                    world_from_camera=model.world_from_camera,
                    clock=clock,
                )
            )
        except CameraUnreachable as e:
            raise UsageError(str(e)) from e
    if camera is None:
        camera = await stack.enter_async_context(
            RealSenseCamera(
                world_from_camera=model.world_from_camera,
                width=config.cell.camera.width,
                height=config.cell.camera.height,
                serial_number=config.hardware.camera_serial or None,
                clock=clock,
            )
        )
    factory = cell_observer_factory(
        config.cell, config.mug_catalogue(), clock=clock, limits=config.camera.frames
    )
    return factory(camera)
