"""The MuJoCo dataset-4 rig job of issue 20 (mugs m2, m5 and m12, depth seed 8), recorded again with who read
each joint sample (``tests/data/rig-mujoco-ds4-reader-race-job.mcap``, see tests/data/README.md): every one
of the job's own joint reads came 9-32 ms after a telemetry poll. Matched by time, the replay handed the
job's second ``plan_for_slot`` a poll's joints (``diverged at 52.801 s in detect (motion): expected
plan_for_slot as recorded, got plan_for_slot for other arguments``); by reader it matches."""

from __future__ import annotations

from pathlib import Path

import pytest

from daemon.recorded import JOB_READER, TELEMETRY_READER
from replay.drivers import _WALL_READ_S
from replay.engine import replay
from replay.session import RecordedSession
from wire.messages import InputJoints

RECORDING = Path(__file__).parents[1] / "data" / "rig-mujoco-ds4-reader-race-job.mcap"


@pytest.fixture(scope="module")
def recorded() -> RecordedSession:
    return RecordedSession.load(RECORDING)


def test_each_of_the_jobs_reads_came_just_after_a_telemetry_poll(recorded: RecordedSession) -> None:
    assert recorded.backend == "hardware"
    samples = sorted(
        (m.t_read, m.reader)
        for m in (r.message for r in recorded.streams["input/joints"])
        if isinstance(m, InputJoints) and isinstance(m.t_read, int | float)
    )
    job = [i for i, (_, reader) in enumerate(samples) if reader == JOB_READER]
    assert len(job) == 4
    for i in job:
        t, before = samples[i][0], samples[i - 1]
        assert before[1] == TELEMETRY_READER
        assert 0.0 < t - before[0] < _WALL_READ_S


@pytest.mark.slow
def test_it_replays_to_a_match(recorded: RecordedSession) -> None:
    report = replay(recorded)
    assert report.first_divergence is None, report.first_divergence
    assert report.replayed.states == recorded.trace.states
    assert report.replayed.final_state == "done"
    assert report.served["motion"] > 0
