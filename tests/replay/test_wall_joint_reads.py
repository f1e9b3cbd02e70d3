"""Which recorded joint sample a joint read of a wall-clock recording gets (issue 20): on the robot each
recorded sample was one read, and the job read no earlier than the replay's job does. A sample recorded
before the replay's read was another read's (a poll's): the job's is the next one not served yet (a MuJoCo
ds4 rig job's second ``plan_for_slot`` was asked with the arm's joints of a poll 30 ms before the job's
own read, and diverged)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import cast

import pytest

from daemon.clock import SessionClock
from replay.drivers import Replayer
from replay.session import RecordedSession
from wire.messages import InputJoints

RECORDING = Path(__file__).parents[1] / "data" / "rig-fault-while-planning-job.mcap"


class _Clock:
    """Only the time a ``Replayer`` reads, set by the test."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        return self.t

    def now(self) -> float:
        return 1.7e9 + self.t


def _replayer(session: RecordedSession) -> tuple[Replayer, _Clock]:
    clock = _Clock()
    replayer = Replayer(session, cast("SessionClock", clock))

    async def start() -> None:
        replayer.job_started()

    asyncio.run(start())
    return replayer, clock


@pytest.fixture(scope="module")
def session() -> RecordedSession:
    s = RecordedSession.load(RECORDING)
    assert not s.simulated
    return s


def _samples(session: RecordedSession) -> list[tuple[float, bool]]:
    """The joint samples' read times and whether each was a read that worked, in order."""
    r, _ = _replayer(session)
    return [
        (t, isinstance(x.message, InputJoints))
        for t, x in zip(r._timed_t["input/joints"], r._timed["input/joints"], strict=True)
    ]


def test_a_read_between_two_samples_gets_the_next_one_not_the_polls_before(session: RecordedSession) -> None:
    samples = _samples(session)
    k = next(
        i
        for i in range(len(samples) - 1)
        if samples[i][1] and samples[i + 1][1] and 0.01 < samples[i + 1][0] - samples[i][0] < 0.1
    )
    replayer, clock = _replayer(session)
    t_k, t_next = samples[k][0], samples[k + 1][0]
    clock.t = (t_k + t_next) / 2 - session.start_monotonic  # (the job started at 0 on both clocks)
    first = replayer.latest("input/joints")
    assert first is replayer._timed["input/joints"][k + 1]
    # A second read at the same moment gets the one after (each sample was one read), if it is near.
    second = replayer.latest("input/joints")
    assert second is not first


def test_a_sample_too_far_ahead_is_not_taken_the_latest_before_is(session: RecordedSession) -> None:
    samples = _samples(session)
    k = next(
        (i for i in range(len(samples) - 1) if samples[i][1] and samples[i + 1][0] - samples[i][0] > 0.25),
        None,
    )
    assert k is not None  # (the recording has such gaps: the FSR and bus threads starved under load)
    replayer, clock = _replayer(session)
    clock.t = samples[k][0] + 0.01 - session.start_monotonic
    assert replayer.latest("input/joints") is replayer._timed["input/joints"][k]
