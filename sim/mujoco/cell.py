"""The simulated cell: the MuJoCo world behind the real drivers, on a simulated clock or in real time.

``open_sim_cell`` starts the physics (``SimWorld``), the simulated Dynamixel chain with the world as its plant
(``drivers.sim.ServoChainSimulator``), the FSR Arduino simulator fed by the world's pad force
(``drivers.sim.FsrSimulator``), then opens the *real* drivers on them — ``DynamixelArm``/``DynamixelGripper``
through dynamixel-sdk and ``FsrReader`` — and the depth camera rendering the world, with the perception
pipeline on top. Everything above this module sees only the ``drivers.interfaces`` and
``perception.interfaces`` protocols; nothing reads the simulator's ground truth except tests and benchmarks
(``cell.world.mug_truths()``).

Two transports carry the bytes between the drivers and the simulators:

- ``"inprocess"`` (the default): ``drivers.sim.inprocess`` cables, on a simulated clock
  (``SteppedClock``) that also steps the world. The cell then runs as fast as the machine allows (or at the
  clock's speed), and the same run gives the same result however loaded the machine is.
- ``"pty"``: pseudo-terminals opened through pyserial like USB adapters, the devices served by their own
  threads in wall-clock time, the world in its own thread at real time × ``speed``; on the wall clock.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import structlog

from description.arm import BUNDLED_URDF
from description.cell import CellLayout, SceneMug
from drivers.dynamixel import DeviceEvent, DynamixelArm, DynamixelGripper
from drivers.dynamixel.health import ChainHealth, HealthLimits
from drivers.fsr.reader import FsrReader
from drivers.interfaces import Camera, Clock, RGBDFrame, SteppedClock
from drivers.sim.fsr import FsrSimulator
from drivers.sim.servo_chain import ServoChainSimulator
from drivers.stack import ARM_JOINTS, gripper_spec
from perception import CameraObserver
from perception.interfaces import MugObserver
from sim.devices import TRANSPORTS, open_cell_devices
from sim.mujoco.arm import build_arm_mjcf, load_urdf
from sim.mujoco.camera import DepthCamera, DepthNoise
from sim.mujoco.collisions import TrayCollision, TrayCollisionCounter
from sim.mujoco.scene import CAMERA_NAME, build_mjcf
from sim.mujoco.world import HeldMug, PhysicsConfig, SimWorld

log = structlog.get_logger("sim.mujoco.cell")

ObserverFactory = Callable[[Camera], MugObserver]


class SnapshotCamera:
    """The world's depth camera: copies the physics state under the world's lock, renders outside it.

    Rendering takes tens of milliseconds; holding the lock that long would stall a physics thread, and
    rendering without it could catch a half-written state. The copy takes microseconds. Frames are stamped
    on the cell's clock.
    """

    def __init__(
        self,
        world: SimWorld,
        *,
        width: int,
        height: int,
        noise: DepthNoise | None,
        seed: int,
        clock: Clock,
    ) -> None:
        self._world = world
        self._clock = clock
        self._data = mujoco.MjData(world.model)
        with world.lock:
            mujoco.mj_copyData(self._data, world.model, world.data)
        self.camera = DepthCamera(
            world.model,
            self._data,
            camera_name=CAMERA_NAME,
            width=width,
            height=height,
            noise=noise,
            seed=seed,
        )
        self.intrinsics = self.camera.intrinsics

    def render(self) -> RGBDFrame:
        with self._world.lock:
            mujoco.mj_copyData(self._data, self._world.model, self._world.data)
        return dataclasses.replace(self.camera.render(), t=self._clock.monotonic())

    async def capture(self) -> RGBDFrame:
        return self.render()

    def close(self) -> None:
        self.camera.close()


# Builds a world of given mugs, joint angles and held mug, stepped like the cell's.
Stager = Callable[
    [Sequence[SceneMug], Mapping[str, float] | None, HeldMug | None],
    tuple[SimWorld, SnapshotCamera, TrayCollisionCounter],
]


class _WorldSwitch:
    """What the devices hang on: the current world, its camera and its collision counter.

    The servo chain's plant, the FSR's force and the camera forward to whatever world is current, so a new
    counter (a new world) needs no new pseudo-terminals, drivers or observer.
    """

    def __init__(self, world: SimWorld, camera: SnapshotCamera, collisions: TrayCollisionCounter) -> None:
        self.world = world
        self.camera = camera
        self.collisions = collisions

    # ServoPlant
    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None:
        self.world.set_goal(servo_id, position_rad, speed_rad_s)

    def present(self, servo_id: int) -> tuple[float, float, float]:
        return self.world.present(servo_id)

    def set_torque(self, servo_id: int, on: bool) -> None:
        self.world.set_torque(servo_id, on)

    # the FSR simulator's force source
    def force_n(self) -> float:
        return self.world.gripper_force_n()

    # drivers.interfaces.Camera
    async def capture(self) -> RGBDFrame:
        return self.camera.render()


@dataclass(slots=True)
class SimCell:
    """The simulated cell's devices (real drivers over pseudo-terminals) and the world behind them.

    ``arm``, ``gripper``, ``force``, ``camera`` and ``observer`` are what a daemon backend runs on;
    ``world`` and ``collisions`` are the simulator's own (ground truth, tray collisions) for tests, benchmarks
    and the collision events.
    """

    layout: CellLayout
    arm: DynamixelArm
    gripper: DynamixelGripper
    force: FsrReader
    observer: MugObserver
    servo_sim: ServoChainSimulator
    fsr_sim: FsrSimulator
    mugs: tuple[SceneMug, ...]
    _switch: _WorldSwitch
    _rebuild: Callable[[Sequence[SceneMug]], tuple[SimWorld, SnapshotCamera, TrayCollisionCounter]]
    _collision_listeners: list[Callable[[TrayCollision], None]] = field(default_factory=list)
    _device_listeners: list[Callable[[DeviceEvent], None]] = field(default_factory=list)
    # The servo chain's health (voltage, temperature, clearing on reset), as on the robot.
    health: ChainHealth | None = None
    # A world of given mugs, joint angles and held mug (``restage``).
    _stage: Stager | None = None

    @property
    def world(self) -> SimWorld:
        return self._switch.world

    @property
    def camera(self) -> Camera:
        return self._switch

    @property
    def collisions(self) -> TrayCollisionCounter:
        """The current world's tray collision counter."""
        return self._switch.collisions

    def on_collision(self, listener: Callable[[TrayCollision], None]) -> None:
        """Call ``listener`` for every tray collision, in this world and the ones later counters bring.

        It runs on the physics thread and must not block (hand it to an event loop with
        ``loop.call_soon_threadsafe``)."""
        self._collision_listeners.append(listener)

    def on_device_event(self, listener: Callable[[DeviceEvent], None]) -> None:
        """Call ``listener`` with every fault and recovery the drivers report (servo faults, bus lost, FSR
        lost or stale, ...), on the event loop."""
        self._device_listeners.append(listener)

    def set_counter(self, mugs: Sequence[SceneMug]) -> None:
        """Put a new set of mugs on the counter: a fresh world with the arm where it is now.

        Call it between jobs (the arm still, nothing in the gripper); the drivers stay connected.
        """
        self._switch_to(self._rebuild(mugs), mugs)
        log.info("simworld_counter_set", mugs=len(mugs))

    def restage(
        self, mugs: Sequence[SceneMug], *, pose: Mapping[str, float], held: HeldMug | None = None
    ) -> None:
        """Set the cell to a state seen elsewhere (a recording's, for a re-simulation): a fresh world with
        ``mugs`` standing where they are (counter or tray; ``held`` among them), the arm and the jaw at
        ``pose`` (joint angles by name), ``held`` in the gripper, settled. The drivers stay connected."""
        if self._stage is None:
            raise RuntimeError("this cell was not built to be restaged")
        self._switch_to(self._stage(mugs, pose, held), mugs)
        log.info("simworld_restaged", mugs=len(mugs), held=held.mug_id if held is not None else None)

    def _switch_to(
        self, built: tuple[SimWorld, SnapshotCamera, TrayCollisionCounter], mugs: Sequence[SceneMug]
    ) -> None:
        world, camera, collisions = built
        old_world, old_camera = self._switch.world, self._switch.camera
        self._switch.world, self._switch.camera, self._switch.collisions = world, camera, collisions
        old_world.stop()
        old_camera.close()
        self.mugs = tuple(mugs)

    def scene(self) -> dict[str, object]:
        """The cell's initial scene for a recording's session header (true poses: the simulator's setup)."""
        return {
            "world": "mujoco",
            "mugs": [
                {
                    "id": m.mug_id,
                    "type": m.spec.name,
                    "x_m": round(m.x_m, 4),
                    "y_m": round(m.y_m, 4),
                    "handle_yaw_rad": round(m.yaw_rad, 4),
                    "upside_down": m.upside_down,
                }
                for m in self.mugs
            ],
        }


async def start_sim_cell(
    layout: CellLayout,
    mugs: Sequence[SceneMug],
    *,
    clock: Clock,
    transport: str = "inprocess",
    speed: float = 1.0,
    seed: int = 0,
    urdf: Path = BUNDLED_URDF,
    physics: PhysicsConfig | None = None,
    start_pose_rad: Sequence[float] | None = None,
    holding_threshold_n: float = 1.0,
    fsr_debounce_s: float = 0.03,
    depth_noise: DepthNoise | None = None,
    observer_factory: ObserverFactory | None = None,
    health: HealthLimits | None = None,
) -> tuple[SimCell, Callable[[], Awaitable[None]]]:
    """Start the simulated cell with ``mugs`` on the counter; returns it and the coroutine that stops it.

    This is the daemon's entry point (``dishbot run --sim --world mujoco``): the cell's ``arm``, ``gripper``,
    ``force`` and ``observer`` make the backend, the returned closer is its ``closer``. Call it on the event
    loop that will use the devices. ``transport`` is ``"inprocess"`` (on a simulated clock, which steps the
    world) or ``"pty"`` (on the wall clock; the world's own thread runs at real time × ``speed``).
    ``start_pose_rad`` places the five arm joints (default: the world's ready pose); ``holding_threshold_n``
    is the FSR reader's "a mug is in the gripper" level (below the grasp threshold, which the squeeze relaxes
    from once the gripper stops closing); ``observer_factory`` turns the camera into the mug observer
    (default: perception's ``CameraObserver``); ``health`` the servos' voltage and temperature limits
    (default ``HealthLimits()``).
    """
    if transport not in TRANSPORTS:
        raise ValueError(f"transport {transport!r}: choose one of {', '.join(TRANSPORTS)}")
    if transport == "pty" and clock.simulated:
        raise ValueError(
            "the pseudo-terminal transport keeps wall-clock time (its devices are served by threads): run it "
            "on the wall clock, or use the in-process transport on a simulated clock"
        )
    stepped = clock if isinstance(clock, SteppedClock) and clock.simulated else None
    arm_mjcf = build_arm_mjcf(load_urdf(urdf))
    make_observer = observer_factory or CameraObserver
    noise = depth_noise if depth_noise is not None else DepthNoise()
    listeners: list[Callable[[TrayCollision], None]] = []

    def dispatch(collision: TrayCollision) -> None:
        for listener in listeners:
            listener(collision)

    def build(
        scene: Sequence[SceneMug], pose: Mapping[str, float] | None, held: HeldMug | None = None
    ) -> tuple[SimWorld, SnapshotCamera, TrayCollisionCounter]:
        xml = build_mjcf(
            layout, scene, arm_body_xml=arm_mjcf.body_xml, arm_actuator_xml=arm_mjcf.actuator_xml
        )
        world = SimWorld(
            xml,
            arm_mjcf,
            mug_ids=[m.mug_id for m in scene],
            speed=speed,
            physics=physics,
            initial_pose_rad=pose,
        )
        if held is not None:
            world.hold(held)
        counter = TrayCollisionCounter(world, layout.tray.region_m, on_collision=dispatch)
        if stepped is not None:
            world.attach(stepped)
        else:
            world.start()
        return world, _camera(world, layout, noise, seed, clock), counter

    switch = _WorldSwitch(*build(mugs, start_pose(start_pose_rad)))
    stack = contextlib.AsyncExitStack()
    stack.callback(lambda: switch.world.stop())
    stack.callback(lambda: switch.camera.close())
    device_listeners: list[Callable[[DeviceEvent], None]] = []

    def device_event(event: DeviceEvent) -> None:
        for listener in device_listeners:
            listener(event)

    try:
        devices = await open_cell_devices(
            switch,
            switch.force_n,
            gripper=arm_mjcf.gripper,
            clock=clock,
            transport=transport,
            stack=stack,
            on_event=device_event,
            holding_threshold_n=holding_threshold_n,
            fsr_debounce_s=fsr_debounce_s,
            health=health,
        )
        servo_sim, fsr_sim = devices.servo_sim, devices.fsr_sim
        arm, gripper, force = devices.stack.arm, devices.stack.gripper, devices.stack.force
    except BaseException:
        await stack.aclose()
        raise

    def rebuild(scene: Sequence[SceneMug]) -> tuple[SimWorld, SnapshotCamera, TrayCollisionCounter]:
        now = {s.joint: switch.present(s.servo_id)[0] for s in arm_mjcf.servos}
        return build(scene, now)

    cell = SimCell(
        layout=layout,
        arm=arm,
        gripper=gripper,
        force=force,
        observer=make_observer(switch),
        servo_sim=servo_sim,
        fsr_sim=fsr_sim,
        mugs=tuple(mugs),
        _switch=switch,
        _rebuild=rebuild,
        _collision_listeners=listeners,
        _device_listeners=device_listeners,
        health=devices.stack.health,
        _stage=build,
    )
    log.info(
        "sim_cell_open",
        mugs=len(mugs),
        transport=transport,
        servo_port=servo_sim.device_path,
        fsr_port=fsr_sim.device_path,
    )
    return cell, stack.aclose


@contextlib.asynccontextmanager
async def open_sim_cell(
    layout: CellLayout,
    mugs: Sequence[SceneMug],
    *,
    clock: Clock,
    transport: str = "inprocess",
    speed: float = 1.0,
    seed: int = 0,
    urdf: Path = BUNDLED_URDF,
    physics: PhysicsConfig | None = None,
    start_pose_rad: Sequence[float] | None = None,
    holding_threshold_n: float = 1.0,
    fsr_debounce_s: float = 0.03,
    depth_noise: DepthNoise | None = None,
    observer_factory: ObserverFactory | None = None,
) -> AsyncIterator[SimCell]:
    """``start_sim_cell`` as an ``async with`` block; stops everything on exit."""
    cell, close = await start_sim_cell(
        layout,
        mugs,
        clock=clock,
        transport=transport,
        speed=speed,
        seed=seed,
        urdf=urdf,
        physics=physics,
        start_pose_rad=start_pose_rad,
        holding_threshold_n=holding_threshold_n,
        fsr_debounce_s=fsr_debounce_s,
        depth_noise=depth_noise,
        observer_factory=observer_factory,
    )
    try:
        yield cell
    finally:
        await close()


def start_pose(start_pose_rad: Sequence[float] | None) -> dict[str, float] | None:
    """The world's initial joint angles from the five arm joints (gripper closed); None: the ready pose.
    ValueError unless there are five finite angles."""
    if start_pose_rad is None:
        return None
    if len(start_pose_rad) != len(ARM_JOINTS) or not all(math.isfinite(v) for v in start_pose_rad):
        raise ValueError(
            f"start_pose_rad needs {len(ARM_JOINTS)} finite joint angles, got {list(start_pose_rad)}"
        )
    pose = dict(zip(ARM_JOINTS, (float(v) for v in start_pose_rad), strict=True))
    pose["gripper"] = 0.0
    return pose


def _camera(
    world: SimWorld, layout: CellLayout, noise: DepthNoise | None, seed: int, clock: Clock
) -> SnapshotCamera:
    return SnapshotCamera(
        world, width=layout.camera.width, height=layout.camera.height, noise=noise, seed=seed, clock=clock
    )


__all__ = [
    "TRANSPORTS",
    "ObserverFactory",
    "SimCell",
    "SnapshotCamera",
    "gripper_spec",
    "open_sim_cell",
    "start_pose",
    "start_sim_cell",
]
