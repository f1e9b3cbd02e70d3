"""The swept collision check (``CollisionWorld.first_collision``) finds what checking every sphere of the
gripper at every densified pose against every obstacle finds: the cheap boxes it screens poses with
(``Sweep``: the grasp-frame box of the spheres carried into the world) only decide where to look, and
the densified poses are those of sampling each gap one pose per centimetre (issue 22)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planning.arm import ArmModel
from planning.motion.collision import Box, CollisionWorld, Cylinder, gripper_spheres

APERTURE_M = 0.08


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _densified(arm: ArmModel, samples: np.ndarray) -> np.ndarray:
    """Each sample preceded by the poses between it and the last, the grasp point moving <= 1 cm."""
    positions, _, _ = arm.fk_many(samples)
    poses = [samples[0]]
    for k in range(1, len(samples)):
        n = math.ceil(float(np.linalg.norm(positions[k] - positions[k - 1])) / 0.01)
        poses += [samples[k - 1] + (samples[k] - samples[k - 1]) * (j / n) for j in range(1, n)]
        poses.append(samples[k])
    return np.array(poses)


def _brute_force(
    arm: ArmModel, samples: np.ndarray, cylinders: list[Cylinder], boxes: list[Box]
) -> tuple[int, str] | None:
    """The first pose where any sphere meets the counter, a cylinder or a box, and what it meets."""
    centres, radii = gripper_spheres(arm.gripper, aperture_m=APERTURE_M)
    for i, q in enumerate(_densified(arm, samples)):
        p, r = arm.fk(q)
        world = p + centres @ r.T
        if np.any(arm.joint_positions(q)[1:, 2] < 0.01):
            return i, "the counter"
        if np.any(world[:, 2] - radii < 0.002):
            return i, "the counter"
        for c in cylinders:
            d = np.hypot(world[:, 0] - c.x, world[:, 1] - c.y)
            if np.any(
                (d < c.radius + radii) & (world[:, 2] + radii > c.z_lo) & (world[:, 2] - radii < c.z_hi)
            ):
                return i, c.name
        for b in boxes:
            nearest = np.clip(world, b.lo, b.hi)
            if np.any(np.linalg.norm(world - nearest, axis=1) < radii):
                return i, b.name
    return None


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_the_first_collision_is_the_one_checking_every_sphere_at_every_pose_finds(
    arm: ArmModel, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.15, -0.4], [0.55, 0.4], size=(8, 2))
    cylinders = [Cylinder(f"mug m{i}", float(x), float(y), 0.04, 0.0, 0.1) for i, (x, y) in enumerate(xy)]
    boxes = [Box("a wall", (0.3, -0.5, 0.0), (0.32, 0.5, 0.05))]
    world = CollisionWorld(arm, cylinders, boxes)
    q0 = rng.uniform(arm.lower * 0.7, arm.upper * 0.7)
    q1 = np.clip(q0 + rng.normal(0.0, 0.4, arm.dof), arm.lower, arm.upper)
    samples = np.linspace(q0, q1, int(rng.integers(2, 7)))
    found = world.first_collision(samples, aperture_m=APERTURE_M)
    expected = _brute_force(arm, samples, cylinders, boxes)
    if expected is None:
        assert found is None
    else:
        assert found is not None
        assert (int(found.why.rsplit("(pose ", 1)[1].split(" of ")[0]), found.obstacle) == expected


def test_a_sweeps_boxes_hold_every_sphere_at_every_pose(arm: ArmModel) -> None:
    rng = np.random.default_rng(5)
    world = CollisionWorld(arm, [], [])
    centres, radii = gripper_spheres(arm.gripper, aperture_m=APERTURE_M)
    samples = rng.uniform(arm.lower, arm.upper, size=(200, arm.dof))
    sweep = world._sweep(samples, centres, radii)
    assert sweep.centres is not None
    lowest = np.min(sweep.centres[:, :, 2] - radii, axis=1)
    assert np.all(sweep.lo <= np.min(sweep.centres - radii[:, None], axis=1))
    assert np.all(sweep.hi >= np.max(sweep.centres + radii[:, None], axis=1))
    assert np.all(sweep.low_bound <= lowest)
    # ... and not much more than them: the gripper is a few centimetres across.
    assert np.all(sweep.hi - sweep.lo < 0.4)
