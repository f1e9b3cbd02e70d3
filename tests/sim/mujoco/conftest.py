"""Fixtures for the physics world: a small cell with a few mugs, and a scripted 'hand' that drives the servos
through the world's ServoPlant methods with the planner's own inverse kinematics."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
import pytest

from description.camera import CameraSpec
from description.cell import CellLayout, SceneMug, Tray
from description.thesis import MugSpec
from planning.arm.grasp import side_grasp
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind, GraspTarget
from sim.mujoco.arm import ArmMjcf, thesis_arm_mjcf
from sim.mujoco.scene import build_mjcf
from sim.mujoco.world import PhysicsConfig, SimWorld

ARM_IDS = (1, 2, 3, 4, 5)
GRIPPER_ID = 6
GRIPPER_OPEN_RAD = -0.35


def small_camera() -> CameraSpec:
    return CameraSpec(64, 48, 60.0, (1.24, 0.07, 0.80), math.pi, math.radians(55.0))


def cell_layout() -> CellLayout:
    """The default cell (tray in the arm's reach), with a tiny camera since these tests do not render."""
    return CellLayout(
        counter_region_m=(-0.30, 0.20, 0.25, 0.52),
        flip_area_center_m=(0.30, -0.40),
        flip_area_radius_m=0.08,
        tray=Tray(origin_m=(0.34, -0.187), size_mm=(332, 374)),
        camera=small_camera(),
    )


@pytest.fixture(scope="session")
def arm_mjcf() -> ArmMjcf:
    return thesis_arm_mjcf()


@pytest.fixture(scope="session")
def arm_model() -> ArmModel:
    return ArmModel.load()


WorldFactory = Callable[..., SimWorld]
Vector: TypeAlias = Sequence[float] | np.ndarray


@pytest.fixture
def make_world(arm_mjcf: ArmMjcf) -> WorldFactory:
    def build(mugs: Sequence[SceneMug], *, physics: PhysicsConfig | None = None) -> SimWorld:
        layout = cell_layout()
        xml = build_mjcf(layout, mugs, arm_body_xml=arm_mjcf.body_xml, arm_actuator_xml=arm_mjcf.actuator_xml)
        return SimWorld(xml, arm_mjcf, mug_ids=[m.mug_id for m in mugs], physics=physics)

    return build


def mug_facing_arm(mug_id: str, spec: MugSpec, x: float, y: float) -> SceneMug:
    """A mug with its handle pointing away from the shoulder axis, out of the gripper's way."""
    return SceneMug(mug_id, spec, x, y, yaw_rad=math.atan2(y, x))


class Hand:
    """Moves the simulated arm the way the servo bus would: joint goals with speeds that finish together."""

    def __init__(self, world: SimWorld, model: ArmModel) -> None:
        self.world = world
        self.model = model

    def joints(self) -> np.ndarray:
        return np.array([self.world.present(i)[0] for i in ARM_IDS])

    def move(self, q: Vector, *, speed_rad_s: float = 1.0, settle_s: float = 0.4) -> float:
        """Move to ``q`` and return the simulated time it took."""
        start = self.world.time()
        delta = np.abs(np.asarray(q) - self.joints())
        duration = max(float(delta.max()) / speed_rad_s, 0.1)
        for servo_id, goal, d in zip(ARM_IDS, q, delta, strict=True):
            self.world.set_goal(servo_id, float(goal), max(float(d) / duration, 1e-3))
        self.world.step_for(duration + settle_s)
        return self.world.time() - start

    def ik(self, position: Vector, kind: GraspKind, seed: Vector | None = None) -> np.ndarray:
        result = self.model.ik(
            GraspTarget((float(position[0]), float(position[1]), float(position[2])), kind),
            seeds=[tuple(seed)] if seed is not None else (),
        )
        assert result.ok, result.reason
        assert result.q is not None
        return np.asarray(result.q)

    def open(self) -> None:
        self.world.set_goal(GRIPPER_ID, GRIPPER_OPEN_RAD, 3.0)
        self.world.step_for(0.8)

    def close_until(self, force_n: float, *, max_rad: float = 1.2) -> bool:
        """Close in small steps, as the gripper driver does, until the pad force passes ``force_n``."""
        angle = self.world.present(GRIPPER_ID)[0]
        while angle < max_rad:
            angle += 0.02
            self.world.set_goal(GRIPPER_ID, angle, 1.0)
            self.world.step_for(0.03)
            if self.world.gripper_force_n() >= force_n:
                self.world.step_for(0.2)
                return True
        return False

    def grasp(
        self, spec: MugSpec, x: float, y: float, *, z: float = 0.06, kind: GraspKind = GraspKind.SIDE
    ) -> np.ndarray:
        """Approach the mug at (x, y) from beside the approach line, close on it; returns the grasp joints."""
        g = side_grasp(x, y, spec, self.model.gripper, z_m=z, kind=kind)
        alpha = g.alpha_rad
        along = np.array([math.cos(alpha), math.sin(alpha), 0.0])
        target = np.asarray(g.target.position_m)
        # The thumb is on the side of the grasp point away from the mug axis (Eq 4.29-4.30).
        # (The grasp point also lies ahead of the axis, the finger tips reaching past it: take the side only.)
        thumb_side = np.append(target[:2] - np.array([x, y]), 0.0)
        thumb_side -= float(thumb_side @ along) * along
        thumb_side /= np.linalg.norm(thumb_side)
        self.open()
        # Come in along the approach line with the mug centred between thumb and finger, then slide the
        # thumb sideways onto it: its face ends tangent to the mug (Eq 4.30); a straight approach brushes it.
        slack = (self.model.gripper.aperture_m(GRIPPER_OPEN_RAD) - spec.diameter_mm / 1000.0) / 2.0
        clear = target + slack * thumb_side
        q = self.ik(clear - 0.06 * along + np.array([0.0, 0.0, 0.15]), kind)
        self.move(q)
        q = self.ik(clear - 0.06 * along, kind, seed=q)
        self.move(q, speed_rad_s=0.5)
        for step in (0.03, 0.0):
            q = self.ik(clear - step * along, kind, seed=q)
            self.move(q, speed_rad_s=0.4, settle_s=0.2)
        q = self.ik(target, kind, seed=q)
        self.move(q, speed_rad_s=0.3)
        return q

    def lift_to(self, position: Vector, kind: GraspKind, seed: Vector, *, step_m: float = 0.02) -> np.ndarray:
        """Move the grasp point along a straight line to ``position`` (IK every ``step_m``); joint-space
        interpolation alone would swing the gripper through whatever stands beside the line."""
        start = np.asarray(self.model.fk(np.asarray(seed))[0])
        goal = np.asarray(position, dtype=np.float64)
        n = max(1, int(np.ceil(np.linalg.norm(goal - start) / step_m)))
        q = np.asarray(seed)
        for k in range(1, n + 1):
            q = self.ik(start + (goal - start) * k / n, kind, seed=q)
            self.move(q, speed_rad_s=0.6, settle_s=0.0 if k < n else 0.4)
        return q


HandFor = Callable[[SimWorld], "Hand"]


@pytest.fixture
def hand_for(arm_model: ArmModel) -> HandFor:
    return lambda world: Hand(world, arm_model)


@dataclass
class OneMug:
    """A world with one mug ``"a"`` standing on the counter facing the arm, and the hand that picks it."""

    world: SimWorld
    hand: Hand
    mug: SceneMug

    def grip(self) -> np.ndarray:
        """Approach the mug and close on it until the pads press 2 N; the grasp's joint angles."""
        q = self.hand.grasp(self.mug.spec, self.mug.x_m, self.mug.y_m)
        assert self.hand.close_until(2.0)
        return q

    def lift(self, q: Vector, *, z_m: float) -> np.ndarray:
        """From the grasp ``q`` straight up to the side grasp at height ``z_m``; the joint angles there."""
        g = side_grasp(self.mug.x_m, self.mug.y_m, self.mug.spec, self.hand.model.gripper, z_m=z_m)
        return self.hand.lift_to(g.target.position_m, GraspKind.SIDE, q)


OneMugFactory = Callable[[MugSpec], OneMug]


@pytest.fixture
def one_mug(make_world: WorldFactory, hand_for: HandFor) -> OneMugFactory:
    """``one_mug(spec)``: a fresh ``OneMug`` world, the mug at (0.24, 0.40) m, in the arm's easy reach."""

    def build(spec: MugSpec) -> OneMug:
        mug = mug_facing_arm("a", spec, 0.24, 0.40)
        world = make_world([mug])
        return OneMug(world, hand_for(world), mug)

    return build
