"""One replay path for every recording (issue 20, items 3-4): a recording of the robot (here the rig's,
``tests/data``, made through the hardware backend) replays to a match in a simulated stand-in; from the
first injected fault the stand-in is set to the world the recording saw then and the job goes on in it,
where the fault keeps its meaning (``at_state`` + ``occurrence`` fire there, each device fault acts on the
stand-in's devices); a job that continued an earlier job's tray replays from what that job left.

For each fault kind the re-simulation ends in the same final state class as a live run of the same fault
on a simulated cell of the stand-in's world with the same mugs
(``test_resimulation_ends_as_the_live_fault_run``)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path

import pytest

from cli.main import main
from replay.engine import ReplayOptions, ReplayReport, fault_text, replay
from replay.faults import FaultInjector, parse_faults
from replay.harness import DishbotReplay
from replay.record import record_job
from replay.resim import continues_earlier_job
from replay.session import RecordedSession

RIG_RECORDING = Path(__file__).parents[1] / "data" / "rig-2mugs-job.mcap"
# The rig recording's mugs (its README says how it was made), for the live runs to compare with.
RIG_MUGS = (("m1", "small", 0.3755, 0.4155), ("m3", "big", 0.0635, 0.4155))

FSR_DROP = {"kind": "fsr_drop", "at_state": "place.transit"}
OVERLOAD = {"kind": "servo_overload", "servo": 3, "at_state": "flip.turn", "after_s": 0.2}
SLIP = {"kind": "mug_slip", "at_state": "flip.transit", "after_s": 0.5}


@pytest.fixture(scope="module")
def rig() -> RecordedSession:
    return RecordedSession.load(RIG_RECORDING)


def with_faults(
    session: RecordedSession, *faults: Mapping[str, object], resim: str | None = None
) -> ReplayReport:
    injector = FaultInjector(parse_faults(fault_text(faults), source="test", config=session.config))
    return replay(session, ReplayOptions(resim=resim), faults=injector)


@pytest.fixture(scope="module")
def restaged(rig: RecordedSession) -> Callable[[Mapping[str, object]], ReplayReport]:
    """The rig's recording replayed with one fault in the kinematic stand-in (a robot recording's own), each
    fault's replay made once for the module: the test of that fault and its comparison with the live run
    (``test_resimulation_ends_as_the_live_fault_run``) look at the same report, which a second replay
    would only give again (seeded, on simulated time)."""
    reports: dict[str, ReplayReport] = {}

    def report(fault: Mapping[str, object]) -> ReplayReport:
        key = fault_text([fault])
        if key not in reports:
            reports[key] = with_faults(rig, fault)
        return reports[key]

    return report


@pytest.mark.slow
def test_a_robot_recording_replays_to_a_match_in_the_kinematic_stand_in(
    rig: RecordedSession, capsys: pytest.CaptureFixture[str]
) -> None:
    report = replay(rig)
    assert report.first_divergence is None, report.first_divergence
    assert report.replayed.states == rig.trace.states
    assert report.replayed.final_state == "done"
    assert report.resimulated_from_s is None  # every input came from the recording
    assert {"observation", "plan", "follow", "grasp", "input/joints", "input/holding"} <= set(report.served)
    assert report.world == "hardware"
    assert "not re-simulated: every input came from the recording (stand-in: kinematic cell" in "\n".join(
        report.lines()
    )
    # The command line: --check passes, and --json says which stand-in and that nothing was re-simulated.
    capsys.readouterr()
    assert main(["--log-level", "warning", "replay", str(RIG_RECORDING), "--check", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (doc["match"], doc["world"], doc["stand_in"], doc["resimulated_from_s"], doc["resim"]) == (
        True,
        "hardware",
        "kinematic",
        None,
        None,
    )


@pytest.mark.slow
def test_a_dropped_force_in_place_transit_recovers_the_mug_in_the_restaged_world(
    rig: RecordedSession, restaged: Callable[[Mapping[str, object]], ReplayReport]
) -> None:
    report = restaged(FSR_DROP)
    (fault,) = report.faults
    assert report.resimulated_from_s == pytest.approx(float(fault["fired_at_s"]), abs=1e-3)  # type: ignore[arg-type]
    assert report.first_divergence is not None
    assert report.first_divergence.what == "fault"
    assert (
        report.replayed.states[: rig.trace.states.index("place.transit") + 1]
        == rig.trace.states[: rig.trace.states.index("place.transit") + 1]
    )
    states = report.replayed.states
    assert "recover_lost_mug" in states[states.index("place.transit") :]
    assert report.replayed.final_state == "done"
    kinds = [e.kind for e in report.replayed.events]
    assert "mug_dropped" in kinds
    # Every mug found and placed, given up, or left out of the plan (the arm's check: the dropped mug can
    # stand in another's way), each with its reason.
    ending = ("mug_placed", "mug_given_up", "slot_dropped", "out_of_reach")
    ends = {e.detail.get("mug_id") for e in report.replayed.events if e.kind in ending}
    assert ends == {"m1", "m2"}, [e.to_json() for e in report.replayed.events if e.kind != "transition"]
    assert all(e.detail.get("reason") for e in report.replayed.events if e.kind in ending[1:])
    # The world it was set to: what the recording saw as place.transit began, m1 in the gripper.
    assert report.resim is not None
    assert report.resim.seen is not None
    assert report.resim.seen.held == "m1"
    assert [m.mug_id for m in report.resim.seen.on("counter")] == ["m2"]
    doc = report.to_json()
    assert doc["resimulated_from_s"] == pytest.approx(report.resimulated_from_s)
    resim = doc["resim"]
    assert isinstance(resim, dict)
    assert resim["world"] == "kinematic"
    assert resim["model_based"] is True
    assert any(
        line.startswith(f"re-simulated from {report.resimulated_from_s:.3f} s in the kinematic stand-in")
        for line in report.lines()
    )


@pytest.mark.slow
def test_an_arm_servo_overloading_in_flip_turn_faults_in_the_restaged_world(
    restaged: Callable[[Mapping[str, object]], ReplayReport],
) -> None:
    report = restaged(OVERLOAD)
    assert report.replayed.final_state == "fault"
    assert report.replayed.state_at(report.replayed.duration_s - 1e-6) == "flip.turn"
    (servo_fault,) = [e for e in report.replayed.events if e.kind == "servo_fault"]
    assert servo_fault.detail["servo_id"] == 3
    fault = next(e for e in report.replayed.events if e.kind == "fault")
    assert "servo 3" in str(fault.detail["reason"])
    assert "overload" in str(fault.detail["reason"])
    assert report.resimulated_from_s is not None


@pytest.mark.slow
def test_a_mug_slipping_in_flip_transit_is_found_and_placed_or_given_up(
    restaged: Callable[[Mapping[str, object]], ReplayReport],
) -> None:
    report = restaged(SLIP)
    (fault,) = report.faults
    assert fault["mug"] == "m1"  # the job's id: the restaged world's mug is the one the job carried
    assert "mug_dropped" in [e.kind for e in report.replayed.events]
    assert report.replayed.final_state == "done"
    ends = {
        e.detail.get("mug_id") for e in report.replayed.events if e.kind in ("mug_placed", "mug_given_up")
    }
    assert "m1" in ends


@pytest.mark.slow
def test_occurrence_counts_entries_in_the_restaged_world(rig: RecordedSession) -> None:
    """A fault due at the second flip.turn fires there, after an earlier fault already moved the job into the
    stand-in: triggers keep counting after the divergence."""
    report = with_faults(rig, {"kind": "fsr_spike", "at_state": "detect"}, {**OVERLOAD, "occurrence": 2})
    assert [o.fired for o in report.fault_outcomes] == [True, True]
    assert report.resimulated_from_s == 0.0  # the spike fired as the job entered detect
    assert report.replayed.final_state == "fault"
    turns = [
        t
        for s, t in zip(report.replayed.states, report.replayed.state_times_s, strict=True)
        if s == "flip.turn"
    ]
    assert len(turns) == 2
    assert float(report.faults[1]["fired_at_s"]) == pytest.approx(turns[1] + 0.2, abs=0.05)  # type: ignore[arg-type]


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
@pytest.mark.parametrize("fault", [FSR_DROP, OVERLOAD, SLIP], ids=lambda f: str(f["kind"]))
def test_resimulation_ends_as_the_live_fault_run(
    fault: Mapping[str, object],
    world: str,
    rig: RecordedSession,
    restaged: Callable[[Mapping[str, object]], ReplayReport],
    tmp_path: Path,
) -> None:
    """The same fault, live on a simulated cell with the rig's mugs, and re-simulated from the rig's
    recording in a stand-in of that world (``--resim``): the same final state class. The kinematic
    stand-in is the one a robot recording takes unasked: its replay is the fault's own test's
    (``restaged``)."""
    injector = FaultInjector(parse_faults(fault_text([fault]), source="test"))
    live = record_job(tmp_path, world=world, mugs=RIG_MUGS, hooks=injector.hooks()).result
    assert [o.fired for o in injector.outcomes()] == [True]
    report = restaged(fault) if world == "kinematic" else with_faults(rig, fault, resim=world)
    assert report.resim is not None
    assert report.resim.world == world
    assert report.resimulated_from_s is not None
    assert report.replayed.final_state == live.end_state
    assert (
        report.replayed.final_state
        == {"fsr_drop": "done", "servo_overload": "fault", "mug_slip": "done"}[str(fault["kind"])]
    )


# --- a job that continued an earlier job's tray -------------------------------------------------------------


@pytest.fixture(scope="module")
def continued(continued_job: Path) -> RecordedSession:
    return RecordedSession.load(continued_job)


@pytest.mark.slow
def test_a_job_continuing_a_tray_replays_from_what_the_earlier_job_left(continued: RecordedSession) -> None:
    assert continues_earlier_job(continued)
    scene_mugs = continued.scene["mugs"]
    assert isinstance(scene_mugs, list)
    assert [m["id"] for m in scene_mugs if m["where"] == "tray"] == ["m1"]
    report = replay(continued)
    assert report.first_divergence is None, report.first_divergence
    assert report.replayed.final_state == "done"
    placed = [e.detail["mug_id"] for e in report.replayed.events if e.kind == "mug_placed"]
    assert placed == [e.detail["mug_id"] for e in continued.trace.events if e.kind == "mug_placed"]
    assert "m1" not in placed  # already on the tray


@pytest.mark.slow
def test_a_fault_in_a_continued_job_restages_the_earlier_jobs_tray(continued: RecordedSession) -> None:
    report = with_faults(continued, SLIP)
    assert report.resim is not None
    assert report.resim.seen is not None
    tray = {m.mug_id: m for m in report.resim.seen.on("tray")}
    assert tray["m1"].source == "header"
    assert report.replayed.final_state == "done"
    # Whatever the job placed after the slip, it placed beside the earlier job's mug, not on it.
    for e in report.replayed.events:
        if e.kind == "mug_placed":
            x, y = e.detail["x_m"], e.detail["y_m"]
            assert isinstance(x, float)
            assert isinstance(y, float)
            assert math.hypot(x - tray["m1"].x_m, y - tray["m1"].y_m) > 0.05


# --- the pytest fixture -------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_pytest_fixture_loads_and_replays_a_rig_recording(dishbot: DishbotReplay) -> None:
    session = dishbot.load(RIG_RECORDING)
    clean = dishbot.replay(session)
    assert clean.match
    assert clean.resimulated_from_s is None
    trace = dishbot.replay(session, faults=[SLIP])
    assert trace.resimulated_from_s is not None
    assert "mug_dropped" in trace.events_by_kind
    assert trace.final_state == "done"


# Every fault kind that acts on a device or on the world, on the robot's recording: it fires in the stand-in
# (with its documented end where docs/faults.md gives one for the kinematic cell's devices).
DEVICE_FAULTS: list[tuple[dict[str, object], str | None]] = [
    ({"kind": "servo_overload", "servo": 2, "at_state": "flip.transit", "after_s": 0.3}, "fault"),
    ({"kind": "servo_overheat", "servo": 2, "at_state": "flip.transit", "after_s": 0.3}, None),
    ({"kind": "servo_voltage", "servo": 2, "at_state": "flip.transit", "after_s": 0.3}, None),
    ({"kind": "servo_silent", "servo": 2, "at_state": "flip.transit", "after_s": 0.3}, "fault"),
    ({"kind": "bus_corrupt", "rate": 1.0, "at_state": "flip.transit", "after_s": 0.3}, "fault"),
    ({"kind": "bus_unplug", "at_state": "flip.transit", "after_s": 0.3}, "fault"),
    ({"kind": "bus_unplug", "device": "fsr", "at_state": "flip.transit", "after_s": 0.3}, None),
    ({"kind": "fsr_drop", "at_state": "flip.transit", "after_s": 0.3}, "done"),
    ({"kind": "fsr_spike", "at_state": "flip.transit", "after_s": 0.3}, "done"),
    ({"kind": "fsr_silent", "at_state": "flip.transit", "after_s": 0.3}, None),
    ({"kind": "camera_no_frame", "at_state": "detect", "occurrence": 2}, None),
    ({"kind": "camera_stale", "at_state": "detect", "occurrence": 2}, None),
    ({"kind": "camera_bad_frame", "at_state": "detect", "occurrence": 2}, None),
    ({"kind": "camera_hang", "at_state": "detect", "occurrence": 2, "duration_s": 1.0}, None),
    ({"kind": "mug_slip", "at_state": "flip.transit", "after_s": 0.3}, "done"),
    ({"kind": "mug_moved", "mug": "m2", "dx_m": 0.02, "at_state": "flip.transit"}, "done"),
]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("fault", "end"), DEVICE_FAULTS, ids=[f"{f['kind']}-{f.get('device', '')}" for f, _ in DEVICE_FAULTS]
)
def test_every_device_fault_kind_acts_on_a_robots_recording(
    fault: Mapping[str, object], end: str | None, rig: RecordedSession
) -> None:
    report = with_faults(rig, fault)
    (outcome,) = report.fault_outcomes
    assert outcome.fired, outcome.line()
    assert report.resimulated_from_s == pytest.approx(outcome.fired_at_s, abs=1e-3)
    assert report.replayed.final_state in ("done", "fault")
    if end is not None:
        assert report.replayed.final_state == end


def test_a_bad_resim_world_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["replay", str(RIG_RECORDING), "--resim", "gazebo"])
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        "dishbot replay: error: argument --resim: invalid choice: 'gazebo' (choose from 'kinematic', "
        "'mujoco')"
    )


@pytest.mark.slow
def test_a_simulated_recordings_header_world_is_a_cross_check(two_mug_job: Path) -> None:
    """A simulated recording builds the stand-in from its header's scene; at the fault the stand-in is set to
    what the recording saw all the same, and the report says how far the header's world was from it (the
    detection noise: millimetres)."""
    report = with_faults(RecordedSession.load(two_mug_job), SLIP)
    assert report.resim is not None
    assert report.resim.from_header
    check = report.resim.check
    assert check is not None
    assert check.startswith("the header's world was within ")
    assert float(check.removeprefix("the header's world was within ").split(" mm")[0]) < 10.0
    assert any(line == f"cross-check: {check}" for line in report.lines())
    assert report.replayed.final_state == "done"
