"""A robot's recording whose device events came while the job computed (issue 20, item 2: a replay of a
robot's log must match). ``tests/data/rig-fault-while-planning-job.mcap`` (see its README) is a job of the
robot rig on a loaded machine: the FSR went stale and came back four times while the job detected and
planned (the plan took 8 s of the robot's wall time), and a servo that did not answer ended the job in
``fault``. Those events must come where they fell in the job's order (before ``cycle_planned``), and the
fault's ``servo_recovered`` before the job's reaction to it, which the stand-in makes at once. A served
plan takes as long on the replay's simulated clock as it took on the robot (issue 20: the daemon's polls
and device events go on through it), so the replay's job moves on when the robot's did."""

from __future__ import annotations

from pathlib import Path

import pytest

from replay.engine import ReplayOptions, ReplayReport, replay
from replay.session import RecordedSession

RECORDING = Path(__file__).parents[1] / "data" / "rig-fault-while-planning-job.mcap"


@pytest.fixture(scope="module")
def recorded() -> RecordedSession:
    return RecordedSession.load(RECORDING)


@pytest.fixture(scope="module")
def replayed(recorded: RecordedSession) -> ReplayReport:
    return replay(recorded)


def test_the_recording_has_device_events_while_the_job_planned(recorded: RecordedSession) -> None:
    assert recorded.backend == "hardware"
    kinds = [(e.kind, e.state) for e in recorded.trace.events if e.kind != "transition"]
    planned = kinds.index(("cycle_planned", "plan"))
    assert kinds[:planned].count(("fsr_stale", "plan")) == 3
    assert kinds[planned + 1 :] == [
        ("servo_fault", "flip.transit"),
        ("servo_recovered", "flip.transit"),
        ("fault", "flip.transit"),
    ]
    assert recorded.trace.final_state == "fault"


@pytest.mark.slow
def test_it_replays_to_a_match_with_every_event_where_it_fell(
    recorded: RecordedSession, replayed: ReplayReport
) -> None:
    report = replayed
    assert report.first_divergence is None, report.first_divergence
    assert [e.kind for e in report.replayed.events] == [e.kind for e in recorded.trace.events]
    assert report.replayed.final_state == "fault"
    assert report.resimulated_from_s is None
    assert report.served["device_event"] == len(recorded.device_events)


@pytest.mark.slow
def test_served_plans_take_as_long_as_on_the_robot_and_the_job_keeps_the_robots_times(
    recorded: RecordedSession, replayed: ReplayReport
) -> None:
    # The plan took 9.9 s of the robot's wall time (detect at 0, plan at 2.7, the first move at 12.6): the
    # replay's job leaves the plan state then too, not as soon as the recorded plans are served.
    assert replayed.replayed.states == recorded.trace.states
    recorded_times = dict(zip(recorded.trace.states, recorded.trace.state_times_s, strict=True))
    assert recorded_times["side_grasp.approach"] - recorded_times["plan"] > 9.0
    for state, t, t_replay in zip(
        recorded.trace.states, recorded.trace.state_times_s, replayed.replayed.state_times_s, strict=True
    ):
        assert t_replay == pytest.approx(t, abs=0.05), state
    # and every event at its time (the FSR's while the job planned among them), the servo's as it failed.
    for e, e_replay in zip(recorded.trace.events, replayed.replayed.events, strict=True):
        assert (e_replay.kind, e_replay.state) == (e.kind, e.state)
        assert e_replay.t_s == pytest.approx(e.t_s, abs=0.05), e.kind


# A job whose placement packing a fault interrupted (see tests/data/README.md): its recording has the plan
# check's motion plans and no placement plan.
PACKING = Path(__file__).parents[1] / "data" / "rig-fault-while-packing-job.mcap"


@pytest.mark.slow
def test_a_packing_the_robot_never_finished_waits_for_the_fault_that_interrupted_it() -> None:
    recorded = RecordedSession.load(PACKING)
    assert recorded.trace.states == ("detect", "plan", "fault")
    assert not recorded.streams.get("plan")
    assert len(recorded.streams["input/motion"]) == 3
    report = replay(recorded)
    # It used to diverge as soon as the served reach plans were done (2.96 s: "plan: expected nothing more
    # recorded, got a plan for m1, m2, m3"): the packing took the robot until the fault, 0.9 s more.
    assert report.first_divergence is None, report.first_divergence
    assert report.served["motion"] == 3
    assert report.served.get("plan", 0) == 0
    assert report.replayed.final_state == "fault"
    _as_on_the_robot(recorded, report)


# A job whose gripper read failed while it planned its first cycle (see tests/data/README.md).
GRIPPER = Path(__file__).parents[1] / "data" / "rig-gripper-failed-while-planning-job.mcap"


@pytest.mark.slow
def test_a_read_that_failed_while_the_robot_planned_fails_while_the_replay_plans() -> None:
    recorded = RecordedSession.load(GRIPPER)
    assert recorded.trace.states == ("detect", "plan", "fault")
    report = replay(recorded)
    # The cycle plan the robot had at 2.8 s was recorded after the daemon's stop at 2.75 s (its reaction to
    # the failed read): it used to be served at once, as the plan check ended (2.3 s), and the replay's job
    # went on to side_grasp.approach before the read failed (at first 0.2 s in, before any plan took time).
    assert report.first_divergence is None, report.first_divergence
    assert report.replayed.final_state == "fault"
    _as_on_the_robot(recorded, report)


# A job whose plan check's probe a fault interrupted (see tests/data/README.md).
PROBING = Path(__file__).parents[1] / "data" / "rig-fault-while-probing-job.mcap"


@pytest.mark.slow
def test_probes_a_faulted_jobs_plan_check_asks_after_the_fault_are_refused_not_a_divergence() -> None:
    recorded = RecordedSession.load(PROBING)
    assert recorded.trace.states == ("detect", "plan", "fault")
    report = replay(recorded)
    assert report.first_divergence is None, report.first_divergence
    assert report.served["motion"] == 1
    _as_on_the_robot(recorded, report)


def _as_on_the_robot(recorded: RecordedSession, report: ReplayReport) -> None:
    """The replay's job had the recorded events, and entered each state within 0.05 s of the robot."""
    assert [e.kind for e in report.replayed.events] == [e.kind for e in recorded.trace.events]
    for t, t_replay in zip(recorded.trace.state_times_s, report.replayed.state_times_s, strict=True):
        assert t_replay == pytest.approx(t, abs=0.05)


@pytest.mark.slow
def test_a_faithful_replay_ends_where_the_recording_does_not_a_job_tail_later(
    recorded: RecordedSession, tmp_path: Path
) -> None:
    """The robot's daemon (``run --once``) stopped about 40 ms after its job faulted, so the job file ends
    there; the replay's daemon stops as long after its job's end (it ran ``recording.job_tail_s``, 2 s, of
    telemetry past anything the recording holds: most of a short replay)."""
    recorded_tail = recorded.end_s - recorded.trace.duration_s
    assert 0.0 < recorded_tail < 0.5 < recorded.config.recording.job_tail_s
    report = replay(recorded, ReplayOptions(record=tmp_path / "again.mcap"))
    assert report.match, report.first_divergence
    again = RecordedSession.load(tmp_path / "again.mcap")
    assert again.trace.states == recorded.trace.states
    assert again.end_s - again.trace.duration_s == pytest.approx(recorded_tail, abs=0.05)
