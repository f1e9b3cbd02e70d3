"""The robot rig without a robot: a simulated cell's devices as the robot's computer sees them.

``open_rig`` starts a simulated world on the wall clock, the simulated Dynamixel chain with the world as its
plant and the FSR Arduino fed by the world's pad force, each on its own pseudo-terminal, and the world's
depth camera for a camera node to publish (``dishbot sim rig`` publishes it on Zenoh). Nothing of the daemon
runs here: the daemon opens the pseudo-terminals through its hardware backend (dynamixel-sdk, the FSR
reader) exactly as it opens the robot's USB adapters, under stable names that stand for the udev rule's
(``<dir>/dishbot-servos``, ``<dir>/dishbot-fsr``).

Two worlds (``RIG_WORLDS``):

- ``mujoco``: the MuJoCo cell's world, the same scene, arm, mugs and depth renderer as ``sim.mujoco.cell``,
  stepped by its own thread at real time;
- ``kinematic``: the kinematic cell's world without dynamics (``sim.kinematic``: the servos go to their
  goals at their speed, a mug the jaw closes on is taken, it lands where it is let go of), behind its servo
  plant, and drawn for the camera by MuJoCo's renderer (``KinematicView``: the same scene, the arm at the
  world's joints, every standing mug where the world has it). The mug in the gripper is not drawn: the
  kinematic world knows its axis on the surface below, not its height in the air.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import mujoco
import numpy as np
import structlog

from description.arm import BUNDLED_URDF
from description.cell import CellLayout, SceneMug
from drivers.interfaces import Clock, RGBDFrame
from drivers.sim.fsr import FsrSimulator
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from planning.arm import ArmModel
from sim.kinematic import KinematicPlant, KinematicWorld, MugGeometry, SimMug
from sim.kinematic.cell import servo_plant
from sim.mujoco.arm import ArmMjcf, build_arm_mjcf, load_urdf
from sim.mujoco.camera import DepthCamera, DepthNoise
from sim.mujoco.cell import SnapshotCamera, start_pose
from sim.mujoco.collisions import TrayCollision, TrayCollisionCounter
from sim.mujoco.scene import CAMERA_NAME, build_mjcf
from sim.mujoco.world import SimWorld

log = structlog.get_logger("sim.rig")

SERVO_LINK = "dishbot-servos"
FSR_LINK = "dishbot-fsr"
RIG_WORLDS: Final = ("mujoco", "kinematic")
# Where the kinematic view puts the mug in the gripper: out of every camera's sight.
_OUT_OF_SIGHT_M: Final = (0.0, 0.0, -50.0)


@dataclass(frozen=True, slots=True)
class Rig:
    """What the rig offers: the device names to open and the camera to publish, and its world (ground truth
    for tests; the daemon never reads it). ``collisions``: the tray collisions the MuJoCo world counts
    (None in the kinematic world, which has no contacts)."""

    servo_port: Path
    fsr_port: Path
    world: SimWorld | KinematicWorld
    mugs: tuple[SceneMug, ...]
    render: Callable[[], RGBDFrame]
    collisions: TrayCollisionCounter | None


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
    world: str = "mujoco",
    seed: int = 0,
    start_pose_rad: Sequence[float] | None = None,
    depth_noise: DepthNoise | None = None,
    on_collision: Callable[[TrayCollision], None] | None = None,
) -> Iterator[Rig]:
    """Start the rig of ``world`` (``RIG_WORLDS``) with ``mugs`` on the counter and its device links in
    ``directory``; everything stops, and the links go, when the block ends. ``clock`` stamps the camera's
    frames and moves the kinematic world (the wall clock: the rig runs at real time). ``on_collision``:
    the MuJoCo world's tray collisions."""
    if world not in RIG_WORLDS:
        raise ValueError(f"world {world!r}: choose one of {', '.join(RIG_WORLDS)}")
    directory.mkdir(parents=True, exist_ok=True)
    arm_mjcf = build_arm_mjcf(load_urdf(BUNDLED_URDF))
    noise = depth_noise if depth_noise is not None else DepthNoise()
    with contextlib.ExitStack() as stack:
        if world == "mujoco":
            pose = start_pose(start_pose_rad)
            xml = build_mjcf(
                layout, mugs, arm_body_xml=arm_mjcf.body_xml, arm_actuator_xml=arm_mjcf.actuator_xml
            )
            sim = SimWorld(xml, arm_mjcf, mug_ids=[m.mug_id for m in mugs], speed=1.0, initial_pose_rad=pose)
            collisions: TrayCollisionCounter | None = TrayCollisionCounter(
                sim, layout.tray.region_m, on_collision=on_collision
            )
            sim.start()
            stack.callback(sim.stop)
            camera = SnapshotCamera(
                sim,
                width=layout.camera.width,
                height=layout.camera.height,
                noise=noise,
                seed=seed,
                clock=clock,
            )
            stack.callback(camera.close)
            plant: SimWorld | KinematicPlant = sim
            force: Callable[[], float] = sim.gripper_force_n
            render: Callable[[], RGBDFrame] = camera.render
            truth: SimWorld | KinematicWorld = sim
        else:
            kinematic, plant = kinematic_world(layout, mugs, clock=clock, start_pose_rad=start_pose_rad)
            view = KinematicView(
                kinematic, plant, layout, mugs, arm_mjcf, noise=noise, seed=seed, clock=clock
            )
            stack.callback(view.close)
            collisions, force, render, truth = None, plant.force_n, view.render, kinematic
        servos = stack.enter_context(ServoChainSimulator(default_chain(), plant=plant))
        fsr = stack.enter_context(FsrSimulator(force))
        servo_port = _link(directory, SERVO_LINK, servos.device_path)
        stack.callback(servo_port.unlink, missing_ok=True)
        fsr_port = _link(directory, FSR_LINK, fsr.device_path)
        stack.callback(fsr_port.unlink, missing_ok=True)
        log.info("rig_open", world=world, servos=str(servo_port), fsr=str(fsr_port), mugs=len(mugs))
        yield Rig(servo_port, fsr_port, truth, tuple(mugs), render, collisions)


def kinematic_world(
    layout: CellLayout, mugs: Sequence[SceneMug], *, clock: Clock, start_pose_rad: Sequence[float] | None
) -> tuple[KinematicWorld, KinematicPlant]:
    """The kinematic cell's world with ``mugs`` on the counter, on ``clock``, and the servo plant that moves
    it (each servo at most at its model's no-load speed, as in ``sim.kinematic.cell``)."""
    arm = ArmModel.load()
    tray = layout.tray
    q0 = None if start_pose_rad is None else np.asarray(start_pose_rad, dtype=np.float64)
    world = KinematicWorld(
        arm,
        [SimMug(m.mug_id, m.spec.name, m.x_m, m.y_m, handle_yaw_rad=m.yaw_rad) for m in mugs],
        {m.spec.name: MugGeometry(m.spec.diameter_mm / 1000.0, m.spec.height_mm / 1000.0) for m in mugs},
        tray_origin_m=tray.origin_m,
        tray_size_m=(tray.size_mm[0] / 1000.0, tray.size_mm[1] / 1000.0),
        clock=clock,
        q0=q0,
    )
    plant = servo_plant(world, arm.gripper, clock)
    return world, plant


class KinematicView:
    """The kinematic world as the depth camera sees it: the cell's MuJoCo scene (``build_mjcf``, the arm
    spliced in) with the arm at the world's joints, the jaw at its opening and every mug standing where the
    world has it (upright or on its brim, handle turned), rendered by ``DepthCamera``. Render on the thread
    that made it (the GL context is that thread's)."""

    def __init__(
        self,
        world: KinematicWorld,
        plant: KinematicPlant,
        layout: CellLayout,
        mugs: Sequence[SceneMug],
        arm_mjcf: ArmMjcf,
        *,
        noise: DepthNoise | None,
        seed: int,
        clock: Clock,
    ) -> None:
        self._world = world
        self._plant = plant
        self._layout = layout
        self._clock = clock
        self._gripper = arm_mjcf.gripper
        self._model = mujoco.MjModel.from_xml_string(build_mjcf(layout, mugs, arm_body_xml=arm_mjcf.body_xml))
        self._data = mujoco.MjData(self._model)
        names = world.arm.joint_names
        self._joints = [
            (self._qpos(s.mj_joint), names.index(s.joint)) for s in arm_mjcf.servos if s.joint in names
        ]
        jaw = next(s for s in arm_mjcf.servos if s.joint == "gripper")
        self._jaw = (self._qpos(jaw.mj_joint), jaw.lower_rad, jaw.upper_rad)
        self._mugs = {m.mug_id: self._qpos(f"{m.body_name}/joint") for m in mugs}
        self._heights = {m.spec.name: m.spec.height_mm / 1000.0 for m in mugs}
        self._pose()
        self.camera = DepthCamera(
            self._model,
            self._data,
            camera_name=CAMERA_NAME,
            width=layout.camera.width,
            height=layout.camera.height,
            noise=noise,
            seed=seed,
        )

    def _qpos(self, joint: str) -> int:
        j = int(mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_JOINT, joint))
        if j < 0:
            raise ValueError(f"the rig's scene has no joint {joint!r}")
        return int(self._model.jnt_qposadr[j])

    def _pose(self) -> None:
        """The scene set to the world as it is now."""
        world, qpos = self._world, self._data.qpos
        q = world.q
        for adr, k in self._joints:
            qpos[adr] = q[k]
        adr, lower, upper = self._jaw
        with contextlib.suppress(ValueError):
            qpos[adr] = min(max(self._gripper.angle_for_aperture(world.aperture_m), lower), upper)
        for mug in list(world.mugs.values()):
            at = self._mugs.get(mug.mug_id)
            if at is None:
                continue
            if mug.where == "gripper":
                qpos[at : at + 3] = _OUT_OF_SIGHT_M
                continue
            half = mug.handle_yaw_rad / 2.0
            z = self._layout.mug_base_z_m(mug.x_m, mug.y_m)
            if mug.upside_down:  # as ``build_mjcf`` stands a mug on its brim
                z += self._heights.get(mug.type, 0.0)
                quat = (0.0, np.cos(half), np.sin(half), 0.0)
            else:
                quat = (np.cos(half), 0.0, 0.0, np.sin(half))
            qpos[at : at + 3] = (mug.x_m, mug.y_m, z)
            qpos[at + 3 : at + 7] = quat
        mujoco.mj_forward(self._model, self._data)

    def render(self) -> RGBDFrame:
        """A frame of the world now, stamped on the rig's clock."""
        self._plant.force_n()  # the plant moves the world lazily: bring it up to now first
        self._pose()
        return dataclasses.replace(self.camera.render(), t=self._clock.monotonic())

    def close(self) -> None:
        self.camera.close()
