"""Device and world faults on the MuJoCo cell, where the real Dynamixel and FSR drivers talk to the byte-level
simulators in-process on simulated time and the camera is rendered: the same fault file as on the kinematic
cell, met through the real driver code. One mug each, and few runs (the physics runs about ten times faster
than real time)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from daemon.app import ServeContext
from daemon.sim_backend import MujocoCounter
from sim.mujoco.cell import SimCell
from tests.replay.faulty import FaultRun, run_with_faults

# Every test here starts a daemon on a simulated cell.
pytestmark = pytest.mark.slow


def cell(run: FaultRun) -> SimCell:
    counter = run.backend.counter
    assert isinstance(counter, MujocoCounter)
    return counter.cell


def test_an_overheated_elbow_in_the_turn_is_the_drivers_servo_fault(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "servo_overheat"\nservo = 3\nat_state = "flip.turn"\n',
        world="mujoco",
        mugs=1,
    )
    assert run.result.end_state == "fault"
    assert run.states[-2:] == ["flip.turn", "fault"]
    assert (run.event("servo_fault")["servo_id"], run.event("servo_fault")["faults"]) == (
        3,
        "['overheating']",
    )
    assert run.event("fault")["reason"] == (
        "ServoFault: servo 3 on inprocess:ttyDXL reports overheating; its torque is off until the fault is "
        "cleared"
    )
    servo = cell(run).servo_sim.servo(3)
    assert servo.get("torque_limit") == 0


def test_a_lasting_gripper_overload_defeats_the_drivers_recoveries(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "servo_overload"\nservo = 6\nat_state = "side_grasp.close"\nduration_s = 5\n',
        world="mujoco",
        mugs=1,
    )
    assert run.result.end_state == "fault"
    assert run.kinds().count("gripper_overload_recovered") == 3
    assert str(run.event("fault")["reason"]).startswith("ServoFault: gripper servo 6 overloaded 4 times")


def test_a_low_supply_sets_the_voltage_register_and_bit_while_the_job_runs(tmp_path: Path) -> None:
    seen: list[tuple[int, int]] = []

    def during(ctx: ServeContext) -> None:
        counter = ctx.backend.counter
        assert isinstance(counter, MujocoCounter)

        async def look() -> None:
            await ctx.clock.sleep(1.0)
            servo = counter.cell.servo_sim.servo(4)
            seen.append((servo.get("present_voltage"), servo.get("min_voltage")))

        asyncio.get_running_loop().create_task(look())

    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "servo_voltage"\nservo = 4\nat_s = 0.5\nduration_s = 2\n',
        world="mujoco",
        mugs=1,
        once=False,
        stop_after_s=3,
        on_ready=during,
    )
    assert seen == [
        (50, 60)
    ]  # the bit it raises is the drivers' tests' (tests/drivers/test_servo_sim_faults.py)
    assert run.injector.fired[0]["ended_at_s"] == 2.5
    assert cell(run).servo_sim.servo(4).get("present_voltage") == 120  # back after duration_s
    # The health poll finds the sagging supply past [hardware.health] voltage_min_v, even at idle.
    assert run.result.end_state == "fault"
    warning = next(e for e in run.events("servo_fault") if e.get("reason") == "voltage")
    assert warning["servo"] == 4


def test_a_silent_force_sensor_while_carrying_is_stale_and_faults(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "fsr_silent"\nat_state = "flip.transit"\n', world="mujoco", mugs=1
    )
    assert run.states[-2:] == ["flip.transit", "fault"]
    assert run.event("fsr_stale")["port"] == "inprocess:ttyFSR"
    assert run.event("fault")["reason"] == "fsr_stale on inprocess:ttyFSR"


def test_a_camera_without_frames_fails_the_look_as_the_realsense_driver_does(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "camera_no_frame"\nat_state = "detect"\n', world="mujoco", mugs=1
    )
    assert run.states == ["detect", "fault"]
    # The driver's own error, after the observer's retries ([camera] frame_retries = 2): a camera fault.
    assert str(run.event("fault")["reason"]).startswith(
        "camera: the RealSense camera sent no frame within 1.0 s"
    )
    counter = run.backend.counter
    assert isinstance(counter, MujocoCounter)
    assert counter.camera is not None
    assert counter.camera.faulty_captures == 3


def test_a_bad_frame_reaches_the_depth_detector_which_refuses_it(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "camera_bad_frame"\nat_state = "detect"\n', world="mujoco", mugs=1
    )
    assert run.states == ["detect", "fault"]
    assert run.event("fault")["reason"] == "camera: bad frame (NaN depth)"  # refused before the detector


def test_a_slipping_mug_falls_out_of_the_physics_gripper_and_the_fsr_sees_it(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "mug_slip"\nat_state = "flip.transit"\nafter_s = 0.5\n',
        world="mujoco",
        mugs=1,
    )
    assert run.injector.fired[0]["world_mug"] == "m1"
    assert run.injector.fired[0]["mug"] == run.event("mug_dropped")["mug_id"]  # the job's id
    assert run.event("mug_dropped")["state"] == "flip.transit"
    assert "recover_lost_mug" in run.states
    truth = cell(run).world.mug_truths()["m1"]
    assert not truth.held
    assert truth.position_m[2] < 0.2  # on the table, not up in the gripper
