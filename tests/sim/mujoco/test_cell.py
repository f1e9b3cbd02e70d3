"""The simulated cell end to end: real drivers moving the MuJoCo arm, grasping a mug, the FSR reader seeing
the force rise and fall, and the camera pipeline seeing the mug. In-process on a simulated clock; the cell
also on pseudo-terminals on the wall clock, the transport that goes through the OS's serial layer (the
hardware backend's tests drive whole jobs over it)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pytest

from daemon.clock import SessionClock
from description.arm import GripperGeometry
from description.camera import CameraSpec
from description.cell import CellLayout
from description.thesis import MUG_TYPES, SMALL_MUG
from drivers.errors import ServoFault
from drivers.interfaces import ArmDriver, Clock, ForceSensor, GripperDriver, JointTrajectory
from perception.interfaces import MugObserver
from planning.arm.grasp import side_grasp
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind, GraspTarget
from sim.counter import counter_mugs
from sim.mujoco.cell import SimCell, gripper_spec, open_sim_cell
from tests.fakes.devices import TRANSPORTS, run_on
from tests.sim.mujoco.conftest import cell_layout

MUG_XY = (0.24, 0.40)


def full_camera_layout() -> CellLayout:
    """The test cell with the configured 640x480 camera at the thesis pose."""
    cam = CameraSpec(640, 480, 64.0, (1.24, 0.07, 0.80), math.pi, math.radians(55.0))
    return replace(cell_layout(), camera=cam)


def _path(
    model: ArmModel, start: Sequence[float], points: Sequence[np.ndarray], kind: GraspKind
) -> JointTrajectory:
    """A trajectory through IK solutions of ``points`` (1 cm apart), 0.5 rad/s on the busiest joint."""
    qs = [np.asarray(start, dtype=np.float64)]
    here = np.asarray(model.fk(qs[0])[0])
    for goal in points:
        n = max(1, int(np.ceil(np.linalg.norm(goal - here) / 0.01)))
        for k in range(1, n + 1):
            r = model.ik(GraspTarget(tuple(here + (goal - here) * k / n), kind), seeds=[tuple(qs[-1])])
            assert r.ok, r.reason
            assert r.q is not None
            qs.append(np.asarray(r.q))
        here = goal
    steps = [float(np.abs(b - a).max()) / 0.5 for a, b in itertools.pairwise(qs)]
    times = np.concatenate([[0.0], np.cumsum(np.maximum(steps, 0.02))])
    return JointTrajectory(tuple(model.joint_names), times, np.vstack(qs))


@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.slow
def test_cell_devices_speak_the_driver_protocols(transport: str) -> None:
    async def body(clock: SessionClock) -> None:
        mugs = counter_mugs([("a", "small", *MUG_XY)], MUG_TYPES)
        async with open_sim_cell(cell_layout(), mugs, clock=clock, transport=transport) as cell:
            assert isinstance(cell.arm, ArmDriver)
            assert isinstance(cell.gripper, GripperDriver)
            assert isinstance(cell.force, ForceSensor)
            assert isinstance(cell.observer, MugObserver)
            js = await cell.arm.read_joints()
            truth = [cell.world.present(i)[0] for i in range(1, 6)]
            np.testing.assert_allclose(js.position_rad, truth, atol=0.01)

    run_on(transport, body)


@pytest.mark.slow
def test_arm_driver_moves_the_physics_arm_and_a_grasp_lifts_then_drops_the_mug() -> None:
    async def body(cell: SimCell, model: ArmModel, clock: Clock) -> None:
        spec = SMALL_MUG
        g = side_grasp(*MUG_XY, spec, model.gripper, z_m=0.06)
        a = g.alpha_rad
        along = np.array([math.cos(a), math.sin(a), 0.0])
        target = np.asarray(g.target.position_m)
        thumb_side = np.append(target[:2] - np.asarray(MUG_XY), 0.0)
        thumb_side /= np.linalg.norm(thumb_side)
        slack = (model.gripper.aperture_m(-0.35) - spec.diameter_mm / 1000.0) / 2.0
        start = (await cell.arm.read_joints()).position_rad
        await cell.gripper.open()
        approach = [
            target + slack * thumb_side - 0.06 * along + np.array([0, 0, 0.15]),
            target + slack * thumb_side - 0.06 * along,
            target + slack * thumb_side,
            target,
        ]
        await cell.arm.follow(_path(model, start, approach, GraspKind.SIDE))
        assert cell.force.latest() is not None
        idle_force = cell.force.latest().force_n  # type: ignore[union-attr]
        result = await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        assert result.held, result.reason
        assert result.aperture_m == pytest.approx(spec.diameter_mm / 1000.0, abs=0.02)
        here = (await cell.arm.read_joints()).position_rad
        await cell.arm.follow(_path(model, here, [target + np.array([0, 0, 0.12])], GraspKind.SIDE))
        await clock.sleep(0.3)
        assert cell.world.held_mug == "a"
        assert cell.world.mug_truths()["a"].position_m[2] > 0.1
        reading = cell.force.latest()
        assert reading is not None
        # The driver holds the pads where they stopped once the force passed the threshold, so the squeeze
        # relaxes a little; it must stay above the reader's release level for the mug to count as held.
        assert reading.force_n > cell.force.release_n > idle_force
        assert cell.force.holding()
        await cell.gripper.open()
        await clock.sleep(0.5)
        assert not cell.force.holding()
        assert cell.force.latest().force_n < 0.5  # type: ignore[union-attr]
        assert cell.world.mug_truths()["a"].position_m[2] < 0.02

    async def main(clock: SessionClock) -> None:
        mugs = counter_mugs([("a", "small", *MUG_XY)], MUG_TYPES)
        async with open_sim_cell(cell_layout(), mugs, clock=clock) as cell:
            await body(cell, ArmModel.load(), clock)

    run_on("inprocess", main)


@pytest.mark.slow
def test_the_camera_pipeline_sees_the_counter_mugs_where_they_are() -> None:
    async def main(clock: SessionClock) -> None:
        mugs = counter_mugs([("a", "small", 0.0, 0.45), ("b", "big", 0.25, 0.45)], MUG_TYPES)
        async with open_sim_cell(full_camera_layout(), mugs, clock=clock) as cell:
            obs = await cell.observer.observe()
            seen = sorted((d.type, round(d.x_m, 2), round(d.y_m, 2)) for d in obs.detections)
            assert [s[0] for s in seen] == ["big", "small"]
            truth = cell.world.mug_truths()
            for d in obs.detections:
                mug = truth["a" if d.type == "small" else "b"]
                assert math.dist((d.x_m, d.y_m), mug.position_m[:2]) < 0.01

    run_on("inprocess", main)


@pytest.mark.slow
def test_a_new_counter_brings_a_new_world_with_the_arm_where_it_was() -> None:
    async def main(clock: SessionClock) -> None:
        layout = cell_layout()
        async with open_sim_cell(layout, [], clock=clock) as cell:
            before = (await cell.arm.read_joints()).position_rad
            cell.set_counter(counter_mugs([("z", "big", 0.1, 0.45)], MUG_TYPES))
            await clock.sleep(0.2)
            assert set(cell.world.mug_truths()) == {"z"}
            after = (await cell.arm.read_joints()).position_rad
            np.testing.assert_allclose(after, before, atol=0.02)
            assert cell.scene()["mugs"] == [
                {
                    "id": "z",
                    "type": "big",
                    "x_m": 0.1,
                    "y_m": 0.45,
                    "handle_yaw_rad": round(math.atan2(0.45, 0.1), 4),  # away from the arm
                    "upside_down": False,
                }
            ]

    run_on("inprocess", main)


@pytest.mark.slow
def test_the_cells_servos_are_watched_and_cleared_as_on_the_robot() -> None:
    """The MuJoCo cell's chain has the robot's health check: polled fine, a tripped servo refused at start
    and cleared by reset's check (issue 13)."""

    async def main(clock: SessionClock) -> None:
        async with open_sim_cell(cell_layout(), [], clock=clock) as cell:
            assert cell.health is not None
            await cell.health.poll()
            cell.servo_sim.overload(2)
            with pytest.raises(ServoFault):
                await cell.arm.read_joints()
            assert cell.health.problems() == ("servo 2 reports overload; reset to clear it",)
            assert await cell.health.clear() == ()
            assert cell.health.problems() == ()
            await cell.arm.read_joints()

    run_on("inprocess", main)


def test_the_pty_transport_is_refused_on_a_simulated_clock() -> None:
    async def main(clock: SessionClock) -> None:
        with pytest.raises(ValueError, match=r"^the pseudo-terminal transport keeps wall-clock time"):
            async with open_sim_cell(cell_layout(), [], clock=clock, transport="pty"):
                pass

    run_on("inprocess", main)


def test_driver_aperture_map_follows_the_planner_gripper() -> None:
    geometry = GripperGeometry()
    spec = gripper_spec(geometry)
    for angle in (-0.3, 0.0, 0.4, 1.2):
        assert spec.aperture_for(angle) == pytest.approx(geometry.aperture_m(angle), abs=2e-3)
