"""Build the kinematic cell: the world without dynamics behind the same devices and drivers as the MuJoCo
cell.

``start_kinematic_cell`` makes the world (``KinematicWorld``), its servo plant and force source
(``sim.kinematic.devices.KinematicPlant``), starts the byte-level servo chain and FSR Arduino simulators on
them and opens the real drivers (``sim.devices.open_cell_devices``: dynamixel-sdk over the in-process chain,
inline on a simulated clock; the FSR reader on the simulated Arduino; the chain's health), and the camera:
``sim.truth.TruthCamera`` behind the camera fault model (``drivers.sim.camera.FaultyCamera``) and perception's
``CameraObserver`` with its frame checks, detecting through ``sim.truth.TruthDetector``. Every device fault is
the simulators' own and acts as in the MuJoCo cell.
"""

from __future__ import annotations

import contextlib
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field

from description.arm import GripperGeometry
from description.servos import SERVO_MODELS
from description.thesis import MUG_TYPES, MugSpec
from drivers.dynamixel import DeviceEvent, DynamixelArm, DynamixelGripper
from drivers.dynamixel.health import ChainHealth, HealthLimits
from drivers.fsr.reader import FsrReader
from drivers.interfaces import Clock, FloatArray
from drivers.sim.camera import FaultyCamera
from drivers.sim.fsr import FsrSimulator
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from perception.interfaces import Detection
from perception.observer import CameraObserver, FrameLimits
from planning.arm import ArmModel
from sim.devices import GRIPPER_SERVO, arm_servos, open_cell_devices
from sim.kinematic.devices import KinematicPlant
from sim.kinematic.world import KinematicWorld, MugGeometry, SimMug
from sim.truth import TruthCamera, TruthDetector

PREVIEW_WIDTH = 16  # the truth camera's frames are this wide: the preview is the frame itself


@dataclass(slots=True)
class KinematicCell:
    """The kinematic cell's devices (real drivers over the device simulators) and the world behind them.

    ``arm``, ``gripper``, ``force``, ``observer`` and ``health`` are what a daemon backend runs on;
    ``servo_sim``, ``fsr_sim`` and ``camera`` are where device faults act (the same hooks as the MuJoCo
    cell's); ``world`` is the simulator's own (ground truth) for tests and the world's faults."""

    world: KinematicWorld
    arm: DynamixelArm
    gripper: DynamixelGripper
    force: FsrReader
    camera: FaultyCamera
    observer: CameraObserver
    servo_sim: ServoChainSimulator
    fsr_sim: FsrSimulator
    health: ChainHealth
    plant: KinematicPlant
    _device_listeners: list[Callable[[DeviceEvent], None]] = field(default_factory=list)

    def on_device_event(self, listener: Callable[[DeviceEvent], None]) -> None:
        """Call ``listener`` with every fault and recovery the drivers report, on the event loop."""
        self._device_listeners.append(listener)


def visible_mugs(world: KinematicWorld) -> list[Detection]:
    """The exact detections of the mugs the camera sees: those standing on the counter or on the tray (not
    the one in the gripper)."""
    return [
        Detection(m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, 1.0)
        for m in world.mugs.values()
        if m.where != "gripper"
    ]


async def start_kinematic_cell(
    mugs: Sequence[SimMug],
    mug_geometry: Mapping[str, MugGeometry],
    *,
    tray_origin_m: tuple[float, float],
    tray_size_m: tuple[float, float],
    clock: Clock,
    holding_threshold_n: float = 1.0,
    fsr_debounce_s: float = 0.03,
    detection_noise_m: float = 0.0,
    seed: int = 0,
    catalogue: Mapping[str, MugSpec] | None = None,
    frame_limits: FrameLimits | None = None,
    health: HealthLimits | None = None,
    arm: ArmModel | None = None,
    q0: FloatArray | None = None,
) -> tuple[KinematicCell, Callable[[], Awaitable[None]]]:
    """The kinematic cell with ``mugs`` on the counter, on ``clock``; returns it and the coroutine that stops
    it. Call it on the event loop that will use the devices. The servos move at most at their models' no-load
    speed. ``holding_threshold_n`` and ``fsr_debounce_s`` are the FSR reader's; ``detection_noise_m`` and
    ``seed`` the detector's; ``catalogue`` the detector's mug types (default: the thesis's); ``frame_limits``
    what a frame must meet (default ``FrameLimits()``); ``health`` the servos' limits (default
    ``HealthLimits()``)."""
    model = arm or ArmModel.load()
    world = KinematicWorld(
        model,
        list(mugs),
        dict(mug_geometry),
        tray_origin_m=tray_origin_m,
        tray_size_m=tray_size_m,
        clock=clock,
        q0=q0,
    )
    plant = servo_plant(world, model.gripper, clock)
    listeners: list[Callable[[DeviceEvent], None]] = []

    def device_event(event: DeviceEvent) -> None:
        for listener in listeners:
            listener(event)

    stack = contextlib.AsyncExitStack()
    try:
        devices = await open_cell_devices(
            plant,
            plant.force_n,
            gripper=model.gripper,
            clock=clock,
            transport="inprocess",
            stack=stack,
            on_event=device_event,
            holding_threshold_n=holding_threshold_n,
            fsr_debounce_s=fsr_debounce_s,
            health=health,
        )
    except BaseException:
        await stack.aclose()
        raise
    truth = TruthCamera(lambda: visible_mugs(world), clock=clock, width=PREVIEW_WIDTH)
    camera = FaultyCamera(truth, clock=clock)
    detector = TruthDetector(truth, catalogue or MUG_TYPES, noise_m=detection_noise_m, seed=seed)
    return KinematicCell(
        world=world,
        arm=devices.stack.arm,
        gripper=devices.stack.gripper,
        force=devices.stack.force,
        camera=camera,
        observer=CameraObserver(
            camera, detector, preview_width=PREVIEW_WIDTH, clock=clock, limits=frame_limits
        ),
        servo_sim=devices.servo_sim,
        fsr_sim=devices.fsr_sim,
        health=devices.stack.health,
        plant=plant,
        _device_listeners=listeners,
    ), stack.aclose


def servo_plant(world: KinematicWorld, gripper: GripperGeometry, clock: Clock) -> KinematicPlant:
    """The servo chain's plant over ``world``: the arm's servos and the gripper's, each no faster than its
    model's no-load speed."""
    return KinematicPlant(
        world,
        arm_servos=arm_servos(),
        gripper_servo=GRIPPER_SERVO,
        gripper=gripper,
        clock=clock,
        max_speed_rad_s={
            servo_id: SERVO_MODELS[servo].no_load_speed_rad_s for servo_id, servo in default_chain()
        },
    )
