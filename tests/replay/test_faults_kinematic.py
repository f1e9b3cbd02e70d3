"""Every fault kind on the kinematic cell, through a real daemon (``serve`` on a simulated clock, the first
two dataset-1 mugs, ``--once``; the first alone where the job goes on after the fault and the second mug
would only add a cycle): the fault happens in the device simulators (the same byte-level servo chain and
FSR Arduino as the MuJoCo cell's, behind the real drivers), at the camera behind the observer's frame checks,
or in the world; the injector reports it (``fired``, a ``fault_injected`` event in the recording), and the
daemon meets it as docs/faults.md says and as it would on the robot: the end state and the events it
publishes say how. (``test_fault_matrix`` runs the same files on both cells and compares them.)"""

from __future__ import annotations

import re
import time
from collections.abc import Mapping
from pathlib import Path

import pytest

from daemon.app import ServeContext
from daemon.clock import SimulatedClock
from daemon.config import Config
from daemon.errors import UsageError
from daemon.sim_backend import KinematicCounter
from drivers.sim.camera import FaultyCamera
from replay.faults import FaultInjector, FaultSpec, parse_faults
from sim.kinematic import KinematicCell, KinematicWorld
from tests.fakes.daemon import serve_daemon
from tests.fakes.job import make_backend, make_world
from tests.replay.faulty import FaultRun, robot_config, run_with_faults

# Every test here starts a daemon on a simulated cell.
pytestmark = pytest.mark.slow

FULL_JOB = [
    "detect",
    "plan",
    "side_grasp.approach",
    "side_grasp.close",
    "side_grasp.verify",
    "side_grasp.lift",
    "flip.transit",
    "flip.turn",
]


PORT = "inprocess:ttyDXL"


def cell(run: FaultRun) -> KinematicCell:
    counter = run.backend.counter
    assert isinstance(counter, KinematicCounter)
    return counter.cell


def world(run: FaultRun) -> KinematicWorld:
    return cell(run).world


def camera(run: FaultRun) -> FaultyCamera:
    return cell(run).camera


def injected(run: FaultRun, kind: str, state: str) -> Mapping[str, object]:
    """The fault fired once, and the recording says so where it fired."""
    assert [f["kind"] for f in run.injector.fired] == [kind]
    event = run.event("fault_injected")
    assert (event["fault"], event["state"], event["index"]) == (kind, state, 1)
    return run.injector.fired[0]


def rect_plan_config() -> Config:
    """The scenarios that name which counter mug the job picks first were written for the rectangle plan's
    order (m2, then m1); the mug-shaped plan (the default footprint) picks them the other way round."""
    return robot_config(planner={"method": "bh", "footprint": "rect"})


def test_an_arm_servo_overload_in_the_turn_faults_the_job_naming_the_servo(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "servo_overload"\nservo = 3\nat_state = "flip.turn"\n')
    assert injected(run, "servo_overload", "flip.turn")["servo"] == 3
    assert run.result.end_state == "fault"
    assert run.states == [*FULL_JOB, "fault"]
    trip = run.event("servo_fault")
    assert (trip["device"], trip["servo_id"], trip["faults"], trip["state"]) == (
        "servo/3",
        3,
        "['overload']",
        "flip.turn",
    )
    assert run.event("fault")["reason"] == (
        f"ServoFault: servo 3 on {PORT} reports overload; its torque is off until the fault is cleared"
    )
    assert cell(run).servo_sim.servo(3).get("torque_limit") == 0  # the 1.0 servo's own shutdown


def test_a_gripper_overload_while_closing_is_recovered_and_the_job_goes_on(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "servo_overload"\nservo = 6\nat_state = "side_grasp.close"\nafter_s = 0.1\n',
        mugs=1,
    )
    injected(run, "servo_overload", "side_grasp.close")
    assert run.result.end_state == "done"
    assert run.kinds().count("gripper_overload_recovered") == 1
    assert run.kinds().count("mug_placed") == 1


def test_a_lasting_gripper_overload_defeats_the_recoveries_and_faults(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "servo_overload"\nservo = 6\nat_state = "side_grasp.close"\nduration_s = 5\n',
    )
    assert run.result.end_state == "fault"
    assert run.kinds().count("gripper_overload_recovered") == 3
    assert str(run.event("fault")["reason"]).startswith("ServoFault: gripper servo 6 overloaded 4 times")


def test_an_overheated_servo_faults_the_job_at_its_next_move(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "servo_overheat"\nservo = 2\nat_state = "plan"\n')
    injected(run, "servo_overheat", "plan")
    assert run.states == ["detect", "plan", "fault"]
    assert run.event("servo_fault")["faults"] == "['overheating']"
    assert f"servo 2 on {PORT} reports overheating" in str(run.event("fault")["reason"])
    assert cell(run).servo_sim.servo(2).get("torque_limit") == 0  # the servo's own shutdown


def test_a_sagging_servo_supply_is_found_by_the_health_poll_and_faults(tmp_path: Path) -> None:
    seen: list[tuple[int, int]] = []

    def during(ctx: ServeContext) -> None:
        async def look() -> None:
            await ctx.clock.sleep(1.5)
            servo = cell_of(ctx).servo_sim.servo(4)
            seen.append((servo.get("present_voltage"), servo.get("min_voltage")))

        import asyncio

        asyncio.get_running_loop().create_task(look())

    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "servo_voltage"\nservo = 4\nat_s = 1\n', on_ready=during
    )
    assert injected(run, "servo_voltage", "side_grasp.approach")["fired_at_s"] == 1.0
    assert seen == [(50, 60)]  # 1 V under the MX-28's 6 V Min Voltage Limit, as the firmware reads it
    # Past [hardware.health] voltage_min_v: the health poll faults the job (docs/faults.md row 2).
    assert run.result.end_state == "fault"
    supply = next(e for e in run.events("servo_fault") if e.get("reason") == "voltage")
    assert supply["servo"] == 4


def cell_of(ctx: ServeContext) -> KinematicCell:
    counter = ctx.backend.counter
    assert isinstance(counter, KinematicCounter)
    return counter.cell


def test_a_silent_servo_is_a_bus_timeout_naming_it(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "servo_silent"\nservo = 3\nat_state = "side_grasp.approach"\n'
    )
    assert run.states == ["detect", "plan", "side_grasp.approach", "fault"]
    assert run.event("servo_fault")["faults"] == "['no_status']"
    assert run.event("fault")["reason"] == (
        f"BusTimeout: servo(s) 3 did not answer on {PORT} after 4 tries; check the cable and power of the "
        "chain"
    )


def test_a_little_line_noise_is_retried_and_the_job_finishes(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "bus_corrupt"\nrate = 0.01\nseed = 3\nat_s = 0\nduration_s = 30\n'
    )
    fired = injected(run, "bus_corrupt", "detect")
    assert (fired["rate"], fired["ended_at_s"]) == (0.01, 30.0)
    assert run.result.end_state == "done"
    assert cell(run).servo_sim.packets_corrupted > 0  # corrupted on the chain, retried by the bus driver
    assert "fault" not in run.kinds()


def test_a_bus_where_every_packet_is_corrupt_faults_the_job(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "bus_corrupt"\nrate = 1.0\nat_state = "side_grasp.approach"\n'
    )
    assert run.states == ["detect", "plan", "side_grasp.approach", "fault"]
    reason = str(run.event("fault")["reason"])
    assert reason.startswith("BusCorrupt: servo(s) ")  # whichever servo the daemon asked first
    assert reason.endswith(
        f" answered only with corrupt packets on {PORT} after 4 tries; check the cable, its connectors and "
        "the supply"
    )


def test_an_unplugged_servo_bus_faults_the_idle_daemon_and_is_back_once_replugged(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "bus_unplug"\nat_s = 1\nduration_s = 1\n',
        once=False,
        stop_after_s=5,
    )
    fired = injected(run, "bus_unplug", "idle")
    assert (fired["device"], fired["fired_at_s"], fired["ended_at_s"]) == ("servo", 1.0, 2.0)
    kinds = run.kinds()
    assert kinds.index("bus_lost") < kinds.index("fault") < kinds.index("bus_restored")
    assert str(run.event("fault")["reason"]).startswith(f"BusLost: servo bus {PORT} is gone (")
    assert run.result.end_state == "fault"  # only reset leaves fault


def test_a_briefly_unplugged_force_sensor_while_carrying_is_forgiven(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "bus_unplug"\ndevice = "fsr"\nat_state = "flip.transit"\nduration_s = 0.1\n',
        mugs=1,
    )
    kinds = run.kinds()
    assert kinds.index("fsr_lost") < kinds.index("fsr_restored")
    assert run.result.end_state == "done"  # back within the job's grace


def test_the_force_dropping_while_carrying_recovers_the_lost_mug(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "fsr_drop"\nat_state = "flip.transit"\nafter_s = 0.5\nduration_s = 1\n',
    )
    fired = injected(run, "fsr_drop", "flip.transit")
    assert fired["ended_at_s"] == pytest.approx(float(fired["fired_at_s"]) + 1.0)  # type: ignore[arg-type]
    assert run.states[:8] == [*FULL_JOB[:7], "recover_lost_mug"]
    assert run.event("mug_dropped")["state"] == "flip.transit"
    assert run.result.end_state == "done"


def test_a_force_spike_is_one_raw_sample_the_filter_keeps_out(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "fsr_spike"\nvalue_n = 30\nat_state = "side_grasp.close"\n', mugs=1
    )
    assert injected(run, "fsr_spike", "side_grasp.close")["value_n"] == 30.0
    forces = [float(p["force_n"]) for t, p in run.recorded if t.endswith("/input/force")]  # type: ignore[arg-type]
    assert forces
    assert max(forces) < 30.0  # the reader's median filter kept the 30 N sample out of the force
    assert "mug_dropped" not in run.kinds()
    assert run.result.end_state == "done"


def test_a_silent_force_sensor_while_carrying_faults_the_job(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "fsr_silent"\nat_state = "flip.transit"\n')
    assert run.states == [*FULL_JOB[:7], "fault"]
    assert run.event("fsr_stale")["device"] == "fsr"
    assert run.event("fault")["reason"] == "fsr_stale on inprocess:ttyFSR"


def test_a_camera_without_a_frame_for_a_moment_is_bridged_by_a_retry(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "camera_no_frame"\nat_state = "detect"\nduration_s = 0.5\n', mugs=1
    )
    injected(run, "camera_no_frame", "detect")
    assert camera(run).faulty_captures == 1  # the first attempt got nothing; the retry got a frame
    assert "fault" not in run.kinds()
    assert run.result.end_state == "done"


def test_a_camera_sending_no_frame_for_good_faults_after_the_retries(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "camera_no_frame"\nat_state = "detect"\n')
    assert run.states == ["detect", "fault"]
    assert run.event("fault")["reason"] == (
        "camera: the RealSense camera sent no frame within 1.0 s: Frame didn't arrive within 1000"
    )
    assert camera(run).faulty_captures == 3  # [camera] frame_retries = 2
    fault_t = float(str(run.event("fault")["t"]))
    assert fault_t == pytest.approx(float(str(run.event("fault_injected")["t"])) + 3.0)


def test_a_stale_camera_faults_the_job_instead_of_showing_placed_mugs(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "camera_stale"\nat_state = "detect"\noccurrence = 2\n')
    injected(run, "camera_stale", "detect")
    assert run.result.end_state == "fault"
    assert re.fullmatch(r"camera: frame \d+\.\d s old", str(run.event("fault")["reason"]))
    assert "mug_given_up" not in run.kinds()


def test_a_bad_frame_is_refused_by_the_frame_checks_and_faults_the_job(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "camera_bad_frame"\nat_state = "detect"\n')
    assert run.states == ["detect", "fault"]
    assert run.event("fault")["reason"] == "camera: bad frame (NaN depth)"


def test_a_camera_hang_that_ends_within_a_retry_lets_the_job_finish(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "camera_hang"\nat_state = "detect"\nduration_s = 3\n', mugs=1
    )
    assert run.injector.fired[0]["ended_at_s"] == 3.0
    assert run.result.end_state == "done"
    assert run.result.summary.duration_s > 3.0


def test_a_camera_hang_for_good_faults_at_the_frame_timeout(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "camera_hang"\nat_state = "detect"\n')
    injected(run, "camera_hang", "detect")
    assert run.states == ["detect", "fault"]
    assert run.event("fault")["reason"] == "camera: no frame within 2.0 s"
    # Three attempts of 2 s each ([camera] frame_timeout_s, frame_retries), not the 60 s state bound.
    fault_t = float(str(run.event("fault")["t"]))
    assert fault_t == pytest.approx(float(str(run.event("fault_injected")["t"])) + 6.0)


def test_a_slipping_mug_really_falls_and_is_recovered(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "mug_slip"\nat_state = "flip.transit"\nafter_s = 0.5\n',
        config=rect_plan_config(),
    )
    fired = injected(run, "mug_slip", "flip.transit")
    assert fired["world_mug"] == "m2"  # the world's mug that was carried (first in the rectangle plan)
    # ... named in the event by the job's id, as the job's own events name it
    assert fired["mug"] == run.event("mug_dropped")["mug_id"]
    assert run.event("mug_dropped")["state"] == "flip.transit"
    assert "recover_lost_mug" in run.states
    assert "mug_found" in run.kinds()
    assert run.result.end_state == "done"
    assert run.result.summary.drops == 1


def test_a_mug_moved_while_the_arm_works_elsewhere_is_moved_in_the_world(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "mug_moved"\nat_state = "side_grasp.lift"\ndx_m = 0.05\ndy_m = -0.01\n',
        config=rect_plan_config(),  # m2 is picked first, m1 waits on the counter
    )
    fired = injected(run, "mug_moved", "side_grasp.lift")
    assert (fired["world_mug"], fired["dx_m"], fired["dy_m"]) == ("m1", 0.05, -0.01)
    # The job's id of that mug: the one its last look saw there.
    seen = [p for t, p in run.recorded if t.endswith("/detections")]
    assert fired["mug"] in {str(m["id"]) for p in seen for m in p["mugs"]}  # type: ignore[attr-defined]
    moved = next(p for t, p in run.recorded if t.endswith("/log") and p.get("event") == "sim_mug_moved")
    assert moved["mug_id"] == "m1"
    assert run.result.end_state == "done"  # the next look finds it where it now is
    assert run.kinds().count("mug_placed") == 2


def test_a_lost_zenoh_peer_is_reported_once_and_once_more_when_it_is_back(tmp_path: Path) -> None:
    def kinds(events: list[dict[str, object]]) -> list[object]:
        return [e["kind"] for e in events]

    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "zenoh_peer_loss"\nat_s = 5\nduration_s = 3\n',
        once=False,
        stop_when=lambda events: "connection_restored" in kinds(events),
    )
    fired = injected(run, "zenoh_peer_loss", "idle")
    assert str(fired["peer"]).startswith("tcp/127.0.0.1:")
    kinds_seen = run.kinds()
    assert kinds_seen.index("fault_injected") < kinds_seen.index("connection_lost")
    assert kinds_seen.index("fault_ended") < kinds_seen.index("connection_restored")
    assert run.event("connection_lost")["peers"] == 0


def test_a_full_disk_costs_only_what_came_while_it_was_full_and_the_job_carries_on(tmp_path: Path) -> None:
    contexts: list[ServeContext] = []
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "disk_full"\nat_s = 1\nduration_s = 2\n',
        mugs=1,
        on_ready=contexts.append,
    )
    assert run.result.end_state == "done"
    recorder = contexts[0].recording.recorder
    assert recorder is not None
    assert recorder.failure is None  # writing went on once there was room
    assert recorder.stats().dropped == run.result.summary.recording_dropped > 0
    assert run.kinds().count("recording_restored") == 1
    # Only what was logged while the disk was full is missing; the job's end is in its file.
    started = min(float(p["t"]) for p in run.events("transition"))  # type: ignore[arg-type]
    times = [float(p["t"]) for _, p in run.recorded if isinstance(p.get("t"), float)]  # type: ignore[arg-type]
    assert [t for t in times if started + 1.01 < t < started + 2.99] == []
    assert max(times) > started + 3.0
    assert run.states[-1] == "done"


def test_a_loop_stall_blocks_the_loop_for_its_wall_time(tmp_path: Path) -> None:
    gaps: list[float] = []
    last = [time.perf_counter()]

    def during(ctx: ServeContext) -> None:
        async def tick() -> None:
            while True:
                await ctx.clock.sleep(0.05)
                now = time.perf_counter()
                gaps.append(now - last[0])
                last[0] = now

        import asyncio

        asyncio.get_running_loop().create_task(tick())

    run = run_with_faults(
        tmp_path, '[[fault]]\nkind = "loop_stall"\nat_s = 1\nduration_s = 0.3\n', mugs=1, on_ready=during
    )
    assert injected(run, "loop_stall", "side_grasp.approach")["stalled_s"] == 0.3
    assert max(gaps) >= 0.3
    assert run.result.end_state == "done"


def test_sigterm_stops_the_daemon_mid_job_and_finishes_the_recording(tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, '[[fault]]\nkind = "sigterm"\nat_state = "flip.turn"\n')
    injected(run, "sigterm", "flip.turn")
    assert run.result.end_state == "flip.turn"
    assert run.states == FULL_JOB
    assert run.logs("daemon_stopping")


def test_two_faults_in_one_file_fire_in_their_order(tmp_path: Path) -> None:
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "fsr_spike"\nat_state = "side_grasp.close"\noccurrence = 2\n\n'
        '[[fault]]\nkind = "mug_slip"\nat_state = "flip"\noccurrence = 2\nafter_s = 0.5\n',
    )
    assert [(f["kind"], f["index"]) for f in run.injector.fired] == [("fsr_spike", 1), ("mug_slip", 2)]
    injections = run.events("fault_injected")
    assert [e["state"] for e in injections] == ["side_grasp.close", "flip.transit"]
    # the second entry of flip is the second mug's (flip.* leaves in between are not new entries)
    flips = [i for i, s in enumerate(run.states) if s == "flip.transit"]
    assert len(flips) >= 2


def test_servo_faults_on_a_servo_the_cell_lacks_are_refused_at_attach(tmp_path: Path) -> None:
    faults = parse_faults('[[fault]]\nkind = "servo_silent"\nservo = 9\nat_s = 1\n', source="f.toml")
    with pytest.raises(
        UsageError, match=r"^fault 1 \(servo_silent\): servo: no servo 9 in the kinematic cell's"
    ):
        run_with_faults(tmp_path, faults)


def test_a_peer_loss_without_a_prepared_peer_is_refused_at_attach(tmp_path: Path) -> None:
    faults = parse_faults('[[fault]]\nkind = "zenoh_peer_loss"\nat_s = 1\n', source="f.toml")
    with pytest.raises(UsageError, match=r"^fault 1 \(zenoh_peer_loss\): the daemon has no peer to lose; "):
        run_with_faults(tmp_path, faults, prepare=False)


def test_the_on_fire_callback_runs_just_before_the_fault_takes_effect(tmp_path: Path) -> None:
    latched_when_called: list[int] = []
    contexts: list[ServeContext] = []
    faults = parse_faults(
        '[[fault]]\nkind = "servo_overload"\nservo = 3\nat_state = "flip.turn"\n', source="f"
    )

    def on_fire(spec: FaultSpec) -> None:
        assert spec is faults[0]
        latched_when_called.append(cell_of(contexts[0]).servo_sim.servo(3).hardware_error)

    run = run_with_faults(tmp_path, faults, on_ready=contexts.append, on_fire=on_fire)
    assert latched_when_called == [0]  # not yet
    assert cell(run).servo_sim.servo(3).hardware_error == 0x20  # the 1.0 overload bit, latched


def test_device_faults_on_a_backend_without_a_simulated_cell_are_refused_at_attach(tmp_path: Path) -> None:
    faults = parse_faults('[[fault]]\nkind = "fsr_drop"\nat_s = 1\n', source="f.toml")
    hooks = FaultInjector(faults).hooks()

    async def run() -> None:
        await serve_daemon(
            robot_config(),
            make_backend(make_world(1)),
            tmp_path / "rec",
            on_publish=hooks.on_publish,
            on_ready=hooks.on_ready,
        )

    with pytest.raises(UsageError) as refused:
        SimulatedClock().run(run())
    assert str(refused.value) == (
        "fault 1 (fsr_drop): the fake backend has no simulated devices or world to fail; fault files run on "
        "the simulated cell (--sim)"
    )


def test_mug_moved_names_the_mug_by_the_jobs_id_and_a_move_it_cannot_make_does_not_fire(
    tmp_path: Path,
) -> None:
    # The job picks its m2 first (the rectangle plan's order: the scenario pins the footprint): while it
    # lifts it, its m1 is moved; m2 is in the gripper, not on the counter; and 0.9 m would put a mug off the
    # counter.
    run = run_with_faults(
        tmp_path,
        '[[fault]]\nkind = "mug_moved"\nmug = "m1"\nat_state = "side_grasp.lift"\ndx_m = -0.03\n\n'
        '[[fault]]\nkind = "mug_moved"\nmug = "m2"\nat_state = "side_grasp.lift"\ndx_m = 0.03\n\n'
        '[[fault]]\nkind = "mug_moved"\nat_state = "side_grasp.lift"\ndx_m = 0.9\n',
        config=rect_plan_config(),
    )
    looks = [p["mugs"] for t, p in run.recorded if t.endswith("/detections")]
    assert all(isinstance(look, list) for look in looks)
    m1 = [(m["x_m"], m["y_m"]) for look in looks for m in look if m["id"] == "m1"]  # type: ignore[attr-defined]
    # The job's own m1 was moved: its next look sees it 3 cm back along x.
    assert m1[1][0] - m1[0][0] == pytest.approx(-0.03, abs=0.005)
    assert m1[1][1] == pytest.approx(m1[0][1], abs=0.005)
    assert [f["mug"] for f in run.injector.fired] == ["m1", "m2", "m1"]
    outcomes = run.injector.outcomes()
    assert [o.fired for o in outcomes] == [True, False, False]
    assert str(outcomes[1].reason).endswith("the job's mug m2 was not standing on the counter")
    assert "off the counter region" in str(outcomes[2].reason)
    assert run.result.end_state == "done"
