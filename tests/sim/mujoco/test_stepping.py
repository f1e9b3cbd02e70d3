"""How the world is stepped and watched: batches of steps and the vectorised contact scan are the same
physics, to the last bit, as stepping one step at a time and asking MuJoCo for every contact's force."""

from __future__ import annotations

import threading
from collections.abc import Sequence

import mujoco
import numpy as np
import pytest

from description.thesis import BIG_MUG, SMALL_MUG
from sim.mujoco.arm import FSR_PAD_GEOM
from sim.mujoco.world import ContactSample, SimWorld
from tests.sim.mujoco.conftest import OneMug, OneMugFactory, WorldFactory, mug_facing_arm

Tick = tuple[float, float, str | None, tuple[tuple[int, int, tuple[float, float, float], float], ...]]


def _record_ticks(world: SimWorld) -> list[Tick]:
    ticks: list[Tick] = []

    def listener(w: SimWorld, t: float, contacts: Sequence[ContactSample]) -> None:
        samples = tuple((c.geom1, c.geom2, c.position, c.normal_force_n) for c in contacts)
        ticks.append((t, w.gripper_force_n(), w.held_mug, samples))

    world.add_contact_listener(listener)
    return ticks


def _step_by_step(world: SimWorld) -> None:
    """Make ``world.step_for`` advance one physics step per batch (as a clock that moves 2 ms at a time)."""
    batch = world.step_for

    def one_at_a_time(seconds: float) -> None:
        for _ in range(max(1, round(seconds / world.physics.timestep_s))):
            batch(world.physics.timestep_s)

    world.step_for = one_at_a_time  # type: ignore[method-assign]


def _grip_lift_and_carry(cell: OneMug) -> None:
    q = cell.lift(cell.grip(), z_m=0.2)
    cell.hand.move(q + np.array([0.4, 0.0, 0.0, 0.0, 0.0]), speed_rad_s=1.5)


def test_a_batch_of_steps_gives_the_same_world_as_one_step_at_a_time_to_the_last_bit(
    one_mug: OneMugFactory,
) -> None:
    batched, stepped = one_mug(SMALL_MUG), one_mug(SMALL_MUG)
    _step_by_step(stepped.world)
    ticks = [_record_ticks(batched.world), _record_ticks(stepped.world)]
    for cell in (batched, stepped):
        _grip_lift_and_carry(cell)
    assert batched.world.held_mug == "a"  # a grasp, a weld and a carry: every path of the monitor ran
    assert batched.world.time() == stepped.world.time()
    assert np.array_equal(batched.world.data.qpos, stepped.world.data.qpos)
    assert np.array_equal(batched.world.data.qvel, stepped.world.data.qvel)
    assert ticks[0] == ticks[1]
    period = batched.world.physics.monitor_period_s
    gaps = np.diff([t for t, *_ in ticks[0]])
    assert gaps.min() == pytest.approx(period)
    assert gaps.max() < period + batched.world.physics.timestep_s


def test_contact_forces_and_the_pad_force_are_mujocos_own(one_mug: OneMugFactory) -> None:
    cell = one_mug(SMALL_MUG)
    world = cell.world
    pad = int(mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_GEOM, FSR_PAD_GEOM))
    checked = {"grasping": 0, "held": 0}
    held_before: list[str | None] = [None]

    def compare(w: SimWorld, t: float, contacts: Sequence[ContactSample]) -> None:
        wrench = np.zeros(6)
        forces: dict[tuple[int, int, tuple[float, ...]], float] = {}
        pad_force = 0.0
        for i in range(w.data.ncon):
            mujoco.mj_contactForce(w.model, w.data, i, wrench)
            a, b = int(w.data.contact.geom1[i]), int(w.data.contact.geom2[i])
            forces[(a, b, tuple(w.data.contact.pos[i].tolist()))] = float(wrench[0])
            if pad in (a, b) and max(w.geom_mug[a], w.geom_mug[b]) >= 0:
                pad_force += float(wrench[0])
        for c in contacts:
            assert c.normal_force_n == forces[(c.geom1, c.geom2, c.position)]
        before, held = held_before[0], w.held_mug
        held_before[0] = held
        if held is None:
            assert w.gripper_force_n() == pad_force
            checked["grasping"] += pad_force > 0.0
        elif before == held:
            # The grip on a mug held since the last tick is never a collision: listeners see only what else
            # it touches (in the tick that welds it, the scan ran before the weld: everything is seen).
            mug = w.mug_ids.index(held)
            for c in contacts:
                assert {int(w.geom_mug[c.geom1]), int(w.geom_mug[c.geom2])} != {mug, -1}
            checked["held"] += 1

    world.add_contact_listener(compare)
    _grip_lift_and_carry(cell)
    assert checked["grasping"] > 10
    assert checked["held"] > 10


def test_the_support_force_is_every_push_on_the_gripped_mug_but_the_grippers(one_mug: OneMugFactory) -> None:
    """The scan's support force (what lets the weld go on a set-down, and keeps a mug resting on something
    from being welded) is the sum, in MuJoCo's contact order, of the normal forces of the contacts between
    the mug in the gripper (held, or between both pads) and anything that is not the gripper."""
    cell = one_mug(SMALL_MUG)
    world = cell.world
    compared = {"held": 0, "pushed": 0}

    def compare(w: SimWorld, t: float, contacts: Sequence[ContactSample]) -> None:
        grip = w._scan_contacts()
        gripped = {w.mug_ids.index(w.held_mug)} if w.held_mug else grip.thumb_mugs & grip.finger_mugs
        wrench = np.zeros(6)
        expected = 0.0
        for i in range(w.data.ncon):
            a, b = (int(g) for g in w.data.contact.geom[i])
            if (w.geom_mug[a] in gripped and not w.geom_gripper[b]) or (
                w.geom_mug[b] in gripped and not w.geom_gripper[a]
            ):
                mujoco.mj_contactForce(w.model, w.data, i, wrench)
                expected += float(wrench[0])
        assert grip.support_force_n == expected
        compared["held"] += w.held_mug is not None
        compared["pushed"] += expected > 0.0

    world.add_contact_listener(compare)
    q = cell.lift(cell.grip(), z_m=0.12)
    # Down onto the counter again: the mug rests on it in the closed gripper, and the weld lets go.
    cell.lift(q, z_m=0.04)
    assert compared["held"] > 10
    assert compared["pushed"] > 10
    assert world.held_mug is None


def test_stepped_by_its_caller_the_servo_states_are_the_physics_as_of_the_last_step(
    make_world: WorldFactory,
) -> None:
    world = make_world([mug_facing_arm("a", BIG_MUG, 0.0, 0.35)])
    world.set_goal(1, 0.3, 1.0)
    for _ in range(3):
        world.step_for(0.05)
        moved = world.data.qpos.copy()
        world.step_for(0.01)  # a second batch before anyone reads: the read sees the latest one
        assert not np.array_equal(world.data.qpos, moved)
        for servo_id in world.servo_ids:
            s = world._servos[servo_id]
            load = float(world.data.actuator_force[s.actuator]) / s.stall_torque
            assert world.present(servo_id) == (
                float(world.data.qpos[s.qpos_adr]),
                float(world.data.qvel[s.dof_adr]),
                min(max(load, -1.0), 1.0),
            )


def test_in_its_own_thread_the_world_answers_servo_reads_without_waiting_for_its_lock(
    make_world: WorldFactory,
) -> None:
    """The bus simulator reads the servos on its own thread while the physics steps in another: a read
    never waits for a batch of steps (the lock is held here by a third thread for the whole read)."""
    world = make_world([mug_facing_arm("a", BIG_MUG, 0.0, 0.35)])
    with world:
        taken, release = threading.Event(), threading.Event()

        def hold_the_lock() -> None:
            with world.lock:
                taken.set()
                release.wait(30.0)

        holder = threading.Thread(target=hold_the_lock)
        holder.start()
        try:
            assert taken.wait(30.0)
            answered: list[tuple[float, float, float]] = []
            reader = threading.Thread(target=lambda: answered.append(world.present(1)))
            reader.start()
            reader.join(30.0)
            assert answered, "the read waited for the world's lock"
        finally:
            release.set()
            holder.join()
