"""The world a recording saw (``replay.resim.world_at``) and the stand-in set to it (``restage``), on the
robot rig's recording in ``tests/data`` (see its README): counter mugs where the camera last saw them, the
mug in the gripper moving with it, a mug set down where the gripper let go of it, placed mugs where the
job put them, the arm at its recorded joints."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from daemon.clock import SimulatedClock
from planning.arm import ArmModel
from replay.resim import WorldMug, first_look_s, world_at
from replay.session import RecordedSession
from sim.kinematic import MugGeometry, SimMug, start_kinematic_cell

RIG_RECORDING = Path(__file__).parents[1] / "data" / "rig-2mugs-job.mcap"


@pytest.fixture(scope="module")
def rig() -> RecordedSession:
    return RecordedSession.load(RIG_RECORDING)


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def state_time(session: RecordedSession, state: str, occurrence: int = 1) -> float:
    times = [t for s, t in zip(session.trace.states, session.trace.state_times_s, strict=True) if s == state]
    return times[occurrence - 1]


def detections(session: RecordedSession) -> list[dict[str, object]]:
    return [
        dict(m.payload)
        for m in session.read.messages
        if m.topic.endswith("/detections") and "/input/" not in m.topic
    ]


def test_a_robot_recording_loads_and_says_it_was_the_hardware_backend(rig: RecordedSession) -> None:
    assert rig.backend == "hardware"
    assert rig.world == "hardware"
    assert not rig.simulated
    assert rig.trace.final_state == "done"


def test_at_the_first_look_the_counter_is_what_the_camera_saw(rig: RecordedSession, arm: ArmModel) -> None:
    first = first_look_s(rig)
    assert first is not None
    world = world_at(rig, first, arm=arm)
    seen = detections(rig)[0]["mugs"]
    assert isinstance(seen, list)
    assert [(m.mug_id, m.type, m.x_m, m.y_m, m.handle_yaw_rad) for m in world.on("counter")] == [
        (d["id"], d["type"], d["x_m"], d["y_m"], d["handle_yaw_rad"])
        for d in sorted(seen, key=lambda d: d["id"])
    ]
    assert all(m.source == "seen" and not m.upside_down for m in world.mugs)
    assert world.on("tray") == ()
    assert world.held is None
    assert not world.holding
    joints = [r for r in rig.streams["input/joints"] if r.t_ns <= rig.start_ns + first * 1e9][-1]
    assert list(world.joints_rad) == joints.payload["position_rad"]
    assert world.describe() == "2 on the counter (m1 m2), 0 on the tray, nothing held"


def test_the_mug_in_the_gripper_is_the_jobs_current_one_and_moves_with_the_arm(
    rig: RecordedSession, arm: ArmModel
) -> None:
    lift = world_at(rig, state_time(rig, "side_grasp.lift") + 0.5, arm=arm)
    turned = world_at(rig, state_time(rig, "flip.set_down") + 0.5, arm=arm)
    for world in (lift, turned):
        assert world.holding
        assert world.held == "m1"
        assert [m.mug_id for m in world.on("counter")] == ["m2"]
        (held,) = world.on("gripper")
        assert held.source == "held"
        p, _r = arm.fk(world.joints_rad)
        # The bottom rides with the gripper: as far from the grasp point as it was at the grasp.
        assert np.linalg.norm(np.asarray(held.bottom_m) - p) == pytest.approx(
            np.linalg.norm(np.asarray(lift.on("gripper")[0].bottom_m) - arm.fk(lift.joints_rad)[0]), abs=1e-9
        )
    assert not lift.on("gripper")[0].upside_down
    assert turned.on("gripper")[0].upside_down  # after the turn-over, on its way to the flip area
    assert turned.on("gripper")[0].axis[2] < -0.9


def test_a_mug_let_go_of_stands_where_the_gripper_released_it(rig: RecordedSession, arm: ArmModel) -> None:
    world = world_at(rig, state_time(rig, "flip.regrasp"), arm=arm)
    assert world.held is None
    assert not world.holding
    m1 = next(m for m in world.mugs if m.mug_id == "m1")
    assert (m1.where, m1.source, m1.upside_down) == ("counter", "released", True)
    fx, fy = rig.config.cell.flip_area_center_m
    assert math.hypot(m1.x_m - fx, m1.y_m - fy) < 0.03  # in the flip area, brim down


def test_placed_mugs_stand_where_the_job_put_them_and_the_tracked_grasp_predicted_it(
    rig: RecordedSession, arm: ArmModel
) -> None:
    placed = {e.detail["mug_id"]: e for e in rig.trace.events if e.kind == "mug_placed"}
    end = world_at(rig, rig.trace.duration_s, arm=arm)
    assert [m.mug_id for m in end.on("tray")] == ["m1", "m2"]
    for m in end.on("tray"):
        assert (m.x_m, m.y_m) == (placed[m.mug_id].detail["x_m"], placed[m.mug_id].detail["y_m"])
        assert m.upside_down
        assert m.source == "placed"
    # Just before the release the held mug's axis, tracked from its grasp, is over the slot it then went to.
    before = world_at(rig, placed["m1"].t_s - 0.5, arm=arm)
    (held,) = before.on("gripper")
    x, y = placed["m1"].detail["x_m"], placed["m1"].detail["y_m"]
    assert isinstance(x, float)
    assert isinstance(y, float)
    assert math.hypot(held.x_m - x, held.y_m - y) < 0.01


def test_the_kinematic_world_is_restaged_to_what_the_recording_saw(
    rig: RecordedSession, arm: ArmModel
) -> None:
    catalogue = rig.config.mug_catalogue()
    tray = rig.config.cell.tray
    seen = world_at(rig, state_time(rig, "flip.transit") + 0.5, arm=arm)
    clock = SimulatedClock()

    def sim(m: WorldMug) -> SimMug:
        return SimMug(m.mug_id, m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, m.where)

    async def scenario() -> None:
        cell, close = await start_kinematic_cell(
            [],
            {n: MugGeometry(m.diameter_mm / 1000.0, m.height_mm / 1000.0) for n, m in catalogue.items()},
            tray_origin_m=tray.origin_m,
            tray_size_m=(tray.size_mm[0] / 1000.0, tray.size_mm[1] / 1000.0),
            clock=clock,
            arm=arm,
        )
        try:
            (held,) = seen.on("gripper")
            await cell.arm.read_joints()  # the devices are up
            cell.world.restage(
                [sim(m) for m in seen.on("counter")], q=seen.joints_rad, held=sim(held), force_n=seen.force_n
            )
            cell.plant.follow_world()
            await clock.sleep(0.5)  # the FSR streams, the servos are polled
            assert cell.world.held == "m1"
            # The servos stand where the world was set: nothing moves it back to where they were.
            assert cell.world.q.tolist() == pytest.approx(list(seen.joints_rad), abs=1e-9)
            js = await cell.arm.read_joints()
            assert list(js.position_rad) == pytest.approx(
                list(seen.joints_rad)[: len(js.position_rad)], abs=0.01
            )
            assert cell.world.pad_force_n() == pytest.approx(seen.force_n)
            assert cell.force.holding()  # the force sensor says what the recording's did
            assert sorted(cell.world.mugs) == ["m1", "m2"]
            # A slip in the restaged world lets the recorded mug fall.
            assert cell.world.drop_held_mug() == "m1"
            assert cell.world.mugs["m1"].where == "counter"
        finally:
            await close()

    clock.run(scenario())
