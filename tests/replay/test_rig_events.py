"""A robot's recording whose device events came while the job computed (issue 20, item 2: a replay of a
robot's log must match). ``tests/data/rig-fault-while-planning-job.mcap`` (see its README) is a job of the
robot rig on a loaded machine: the FSR went stale and came back four times while the job detected and
planned (the plan took 8 s of the robot's wall time), and a servo that did not answer ended the job in
``fault``. A replay's planning takes no simulated time, so those events must come where they fell in the
job's order (before ``cycle_planned``), and the fault's ``servo_recovered`` before the job's reaction to
it, which the stand-in makes at once."""

from __future__ import annotations

from pathlib import Path

import pytest

from replay.engine import replay
from replay.session import RecordedSession

RECORDING = Path(__file__).parents[1] / "data" / "rig-fault-while-planning-job.mcap"


@pytest.fixture(scope="module")
def recorded() -> RecordedSession:
    return RecordedSession.load(RECORDING)


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
def test_it_replays_to_a_match_with_every_event_where_it_fell(recorded: RecordedSession) -> None:
    report = replay(recorded)
    assert report.first_divergence is None, report.first_divergence
    assert [e.kind for e in report.replayed.events] == [e.kind for e in recorded.trace.events]
    assert report.replayed.final_state == "fault"
    assert report.resimulated_from_s is None
    assert report.served["device_event"] == len(recorded.device_events)
