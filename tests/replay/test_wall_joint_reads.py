"""Which recorded joint sample a joint read of a wall-clock recording gets (issue 20): on the robot each
recorded sample was one read, and the job read no earlier than the replay's job does. A sample recorded
before the replay's read was another read's (a poll's): the job's is the next one not served yet (a MuJoCo
ds4 rig job's second ``plan_for_slot`` was asked with the arm's joints of a poll 30 ms before the job's
own read, and diverged)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import cast

import msgspec
import pytest

from daemon.clock import SessionClock
from daemon.recorded import JOB_READER, TELEMETRY_READER, joint_reader
from drivers.interfaces import ArmDriver
from replay.drivers import ReplayArm, Replayer
from replay.session import Recorded, RecordedSession
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


# --- who read (``input/joints``'s ``reader``) --------------------------------------------------------------

_TELEMETRY_AT = (0.90, 1.00, 1.10)  # the telemetry's polls, s after the job's start (recorded monotonic)


def _with_readers(session: RecordedSession, job_at: tuple[float, ...]) -> RecordedSession:
    """``session`` with its joint samples replaced by the telemetry's at ``_TELEMETRY_AT`` and the job's own
    at ``job_at``: each sample's first joint angle says whose it is (10 + its number for the telemetry's, 20
    + its number for the job's)."""
    template = next(r.message for r in session.streams["input/joints"] if isinstance(r.message, InputJoints))
    assert isinstance(template, InputJoints)
    start = session.start_monotonic

    def sample(at: float, reader: str, first: float) -> Recorded:
        message = msgspec.structs.replace(
            template, t_read=start + at, reader=reader, position_rad=[first, *template.position_rad[1:]]
        )
        t_ns = round((start + at + session.mono_offset_s) * 1e9)
        return Recorded("input/joints", t_ns, msgspec.to_builtins(message), message)

    samples = [sample(at, TELEMETRY_READER, 10.0 + k) for k, at in enumerate(_TELEMETRY_AT)]
    samples += [sample(at, JOB_READER, 20.0 + k) for k, at in enumerate(job_at)]
    samples.sort(key=lambda r: r.t_ns)
    return session.with_streams({"input/joints": tuple(samples), "input/joints_failed": ()})


def _read(replayer: Replayer, reader: str) -> float:
    """The first joint angle a read by ``reader`` gets through the replay's arm now."""
    arm = ReplayArm(cast("ArmDriver", None), replayer)  # (while served, the cell's arm is never read)

    async def read() -> float:
        with joint_reader(reader):
            return (await arm.read_joints()).position_rad[0]

    return asyncio.run(read())


@pytest.mark.parametrize(
    ("job_at", "reads"),
    [
        # The robot's job read 30 ms after the poll at 1.00 s; the replay's job reads at 0.99 s, just before
        # that poll: the next sample not served yet, the poll's, is not the job's.
        ((1.03,), [(0.99, JOB_READER, 20.0), (1.00, TELEMETRY_READER, 11.0)]),
        # The other order: the robot's job read at 0.98 s, just before the poll at 1.00 s; the replay's
        # telemetry polls first (the poll it is is the one at 1.00 s), then its job reads.
        ((0.98,), [(0.97, TELEMETRY_READER, 11.0), (0.975, JOB_READER, 20.0), (1.0, TELEMETRY_READER, 11.0)]),
        # Two reads of the job close together, a poll between them: each its own, in order.
        ((1.02, 1.05), [(1.01, JOB_READER, 20.0), (1.01, TELEMETRY_READER, 12.0), (1.01, JOB_READER, 21.0)]),
    ],
)
def test_each_reader_gets_its_own_sample_whatever_came_between(
    session: RecordedSession, job_at: tuple[float, ...], reads: list[tuple[float, str, float]]
) -> None:
    """The race of the MuJoCo ds4 rig session (issue 20): the telemetry's poll and the job's own read within
    ``_WALL_READ_S`` of each other. Matched by time, one reader got the other's sample."""
    replayer, clock = _replayer(_with_readers(session, job_at))
    for at, reader, first in reads:
        clock.t = at  # (the job started at 0 on the replay's clock, at start_monotonic on the recording's)
        assert _read(replayer, reader) == first, f"{reader} at {at} s"
