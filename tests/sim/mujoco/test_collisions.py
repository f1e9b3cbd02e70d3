"""Tray collision accounting: what counts as a collision, once, and only over the tray."""

from __future__ import annotations

import mujoco
import pytest

from description.cell import SceneMug
from description.thesis import SMALL_MUG, TOLERANCE_MM
from planning.arm.grasp import side_grasp
from planning.arm.targets import GraspKind
from sim.mujoco.collisions import TrayCollision, TrayCollisionCounter
from sim.mujoco.world import ContactSample, SimWorld
from tests.sim.mujoco.conftest import HandFor, WorldFactory, cell_layout, mug_facing_arm

TRAY = cell_layout().tray.region_m


def _geom(world: SimWorld, name: str) -> int:
    return int(mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_GEOM, name))


def _sample(world: SimWorld, g1: str, g2: str, xy: tuple[float, float], force: float = 2.0) -> ContactSample:
    return ContactSample(_geom(world, g1), _geom(world, g2), (xy[0], xy[1], 0.05), force)


@pytest.fixture
def two_mugs(make_world: WorldFactory) -> SimWorld:
    return make_world([mug_facing_arm("a", SMALL_MUG, 0.0, 0.30), mug_facing_arm("b", SMALL_MUG, 0.15, 0.30)])


def test_touching_mugs_over_the_tray_count_once_until_they_part(two_mugs: SimWorld) -> None:
    world = two_mugs
    seen: list[TrayCollision] = []
    counter = TrayCollisionCounter(world, TRAY, on_collision=seen.append, rearm_s=0.25)
    touch = [_sample(world, "mug/a/body", "mug/b/body", (0.5, 0.0))]
    counter._on_contacts(world, 1.0, touch)
    counter._on_contacts(world, 1.1, touch)  # still resting against each other
    counter._on_contacts(world, 1.3, touch)
    assert counter.counts() == {"mug_mug": 1, "gripper_mug": 0}
    counter._on_contacts(world, 1.7, touch)  # apart for 0.4 s, then touching again
    assert counter.count == 2
    assert seen == counter.collisions
    assert seen[0].to_event() == {
        "event": "tray_collision",
        "t": 1.0,
        "kind": "mug_mug",
        "a": "a",
        "b": "b",
        "position_m": [0.5, 0.0, 0.05],
        "force_n": 2.0,
    }


def test_contacts_off_the_tray_or_too_light_are_not_collisions(two_mugs: SimWorld) -> None:
    world = two_mugs
    counter = TrayCollisionCounter(world, TRAY)
    counter._on_contacts(world, 1.0, [_sample(world, "mug/a/body", "mug/b/body", (0.0, 0.3))])  # counter
    counter._on_contacts(world, 2.0, [_sample(world, "mug/a/body", "mug/b/body", (0.5, 0.0), force=0.01)])
    assert counter.count == 0


def test_gripper_touching_a_mug_it_does_not_handle_is_a_collision(two_mugs: SimWorld) -> None:
    world = two_mugs
    counter = TrayCollisionCounter(world, TRAY)
    counter._on_contacts(world, 1.0, [_sample(world, "gripper/fsr_pad", "mug/b/body", (0.5, 0.0))])
    assert [(c.kind, c.a, c.b) for c in counter.collisions] == [("gripper_mug", "gripper", "b")]


def test_bad_tray_region_is_refused(two_mugs: SimWorld) -> None:
    with pytest.raises(
        ValueError, match=r"^tray_region_m must be \(x_min, y_min, x_max, y_max\), got \(1, 0, 0, 1\)$"
    ):
        TrayCollisionCounter(two_mugs, (1, 0, 0, 1))


def _place_next_to(make_world: WorldFactory, hand_for: HandFor, gap_m: float) -> TrayCollisionCounter:
    """Carry a small mug from the counter to the tray, handle first towards a mug already standing there."""
    place_xy = (0.48, -0.02)
    reach = (SMALL_MUG.width_mm - SMALL_MUG.diameter_mm / 2) / 1000.0  # handle tip ahead of the axis
    radius = SMALL_MUG.diameter_mm / 2000.0
    standing = SceneMug("b", SMALL_MUG, place_xy[0] + reach + radius + gap_m, place_xy[1], yaw_rad=0.0)
    moving = mug_facing_arm("a", SMALL_MUG, 0.24, 0.40)
    world = make_world([moving, standing])
    counter = TrayCollisionCounter(world, TRAY)
    hand = hand_for(world)
    q = hand.grasp(SMALL_MUG, moving.x_m, moving.y_m)
    assert hand.close_until(2.0)
    carry = side_grasp(moving.x_m, moving.y_m, SMALL_MUG, hand.model.gripper, z_m=0.25)
    q = hand.lift_to(carry.target.position_m, GraspKind.SIDE, q)
    above = side_grasp(*place_xy, SMALL_MUG, hand.model.gripper, z_m=0.25)
    q = hand.lift_to(above.target.position_m, GraspKind.SIDE, q)
    down = side_grasp(*place_xy, SMALL_MUG, hand.model.gripper, z_m=0.006 + 0.06 + 0.008)
    hand.lift_to(down.target.position_m, GraspKind.SIDE, q)
    hand.open()
    world.step_for(0.5)
    return counter


def test_placing_with_the_thesis_tolerance_makes_no_collision(
    make_world: WorldFactory, hand_for: HandFor
) -> None:
    counter = _place_next_to(make_world, hand_for, gap_m=TOLERANCE_MM / 1000.0)
    assert counter.collisions == []


def test_placing_into_a_neighbour_counts_the_collision(make_world: WorldFactory, hand_for: HandFor) -> None:
    counter = _place_next_to(make_world, hand_for, gap_m=-0.008)
    assert counter.counts()["mug_mug"] >= 1
    assert {(c.a, c.b) for c in counter.collisions if c.kind == "mug_mug"} == {("a", "b")}
