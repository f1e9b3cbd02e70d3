"""The robot rig without a robot: the MuJoCo cell's devices as the robot's computer sees them.

``open_rig`` starts the physics world in its own thread at real time, the simulated Dynamixel chain with the
world as its plant and the FSR Arduino fed by the world's pad force, each on its own pseudo-terminal, and the
world's depth camera for a camera node to publish (``dishbot sim rig`` publishes it on Zenoh). Nothing of the
daemon runs here: the daemon opens the pseudo-terminals through its hardware backend (dynamixel-sdk, the FSR
reader) exactly as it opens the robot's USB adapters, under stable names that stand for the udev rule's
(``<dir>/dishbot-servos``, ``<dir>/dishbot-fsr``).

The world is the MuJoCo cell's world: the same scene, arm, mugs and depth renderer as ``sim.mujoco.cell``,
in wall-clock time. The kinematic world has no depth renderer, so it has no rig.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import structlog

from description.arm import BUNDLED_URDF
from description.cell import CellLayout, SceneMug
from drivers.interfaces import Clock, RGBDFrame
from drivers.sim.fsr import FsrSimulator
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from sim.mujoco.arm import build_arm_mjcf, load_urdf
from sim.mujoco.camera import DepthNoise
from sim.mujoco.cell import SnapshotCamera, start_pose
from sim.mujoco.collisions import TrayCollision, TrayCollisionCounter
from sim.mujoco.scene import build_mjcf
from sim.mujoco.world import SimWorld

log = structlog.get_logger("sim.rig")

SERVO_LINK = "dishbot-servos"
FSR_LINK = "dishbot-fsr"


@dataclass(frozen=True, slots=True)
class Rig:
    """What the rig offers: the device names to open and the camera to publish, and its world (ground truth
    for tests; the daemon never reads it)."""

    servo_port: Path
    fsr_port: Path
    world: SimWorld
    mugs: tuple[SceneMug, ...]
    render: Callable[[], RGBDFrame]
    collisions: TrayCollisionCounter


def _link(directory: Path, name: str, target: str) -> Path:
    """``directory/name`` -> ``target``, replacing a link a rig that died left behind (never a real file)."""
    path = directory / name
    if path.is_symlink():
        path.unlink()
    elif path.exists():
        raise FileExistsError(f"{path} exists and is not a link a rig left: choose another --dir")
    os.symlink(target, path)
    return path


@contextlib.contextmanager
def open_rig(
    layout: CellLayout,
    mugs: Sequence[SceneMug],
    *,
    directory: Path,
    clock: Clock,
    seed: int = 0,
    start_pose_rad: Sequence[float] | None = None,
    depth_noise: DepthNoise | None = None,
    on_collision: Callable[[TrayCollision], None] | None = None,
) -> Iterator[Rig]:
    """Start the rig with ``mugs`` on the counter and its device links in ``directory``; everything stops,
    and the links go, when the block ends. ``clock`` stamps the camera's frames (the wall clock: the world
    runs at real time)."""
    pose = start_pose(start_pose_rad)
    directory.mkdir(parents=True, exist_ok=True)
    arm_mjcf = build_arm_mjcf(load_urdf(BUNDLED_URDF))
    xml = build_mjcf(layout, mugs, arm_body_xml=arm_mjcf.body_xml, arm_actuator_xml=arm_mjcf.actuator_xml)
    world = SimWorld(xml, arm_mjcf, mug_ids=[m.mug_id for m in mugs], speed=1.0, initial_pose_rad=pose)
    with contextlib.ExitStack() as stack:
        collisions = TrayCollisionCounter(world, layout.tray.region_m, on_collision=on_collision)
        world.start()
        stack.callback(world.stop)
        camera = SnapshotCamera(
            world,
            width=layout.camera.width,
            height=layout.camera.height,
            noise=depth_noise if depth_noise is not None else DepthNoise(),
            seed=seed,
            clock=clock,
        )
        stack.callback(camera.close)
        servos = stack.enter_context(ServoChainSimulator(default_chain(), plant=world))
        fsr = stack.enter_context(FsrSimulator(world.gripper_force_n))
        servo_port = _link(directory, SERVO_LINK, servos.device_path)
        stack.callback(servo_port.unlink, missing_ok=True)
        fsr_port = _link(directory, FSR_LINK, fsr.device_path)
        stack.callback(fsr_port.unlink, missing_ok=True)
        log.info("rig_open", servos=str(servo_port), fsr=str(fsr_port), mugs=len(mugs))
        yield Rig(servo_port, fsr_port, world, tuple(mugs), camera.render, collisions)
