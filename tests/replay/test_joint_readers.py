"""Each recorded joint sample says who read it (``input/joints``'s ``reader``, issue 20): the job's own reads
(its plans and moves start from them) and the telemetry's joints poll, so that a replay hands each reader its
own sample (``tests/replay/test_wall_joint_reads.py``)."""

from __future__ import annotations

import asyncio
from collections import Counter
from pathlib import Path

import pytest

from daemon.clock import RealClock
from daemon.recorded import JOB_READER, TELEMETRY_READER, JobPosition, _RecordedArm, joint_reader
from drivers.errors import BusLost
from drivers.interfaces import JointState, JointTrajectory
from replay.drivers import Replayer
from replay.engine import replay
from replay.session import RecordedSession
from wire.messages import InputJoints, Payload, ReadFailed


class _Arm:
    """An arm whose reads work, then fail (the bus unplugged)."""

    joint_names = ("a", "b")

    def __init__(self) -> None:
        self.unplugged = False

    async def read_joints(self) -> JointState:
        if self.unplugged:
            raise BusLost("the servo chain's port is gone", port="/dev/ttyDXL")
        return JointState(
            t=1.0, names=self.joint_names, position_rad=(0.1, 0.2), velocity_rad_s=(0, 0), load=(0, 0)
        )

    async def follow(self, trajectory: JointTrajectory) -> None:
        raise AssertionError("not moved here")

    async def stop(self) -> None:
        pass

    async def relax(self) -> None:
        pass


def test_a_read_is_recorded_as_the_jobs_unless_its_reader_says_otherwise() -> None:
    recorded: list[tuple[str, Payload]] = []
    inner = _Arm()
    arm = _RecordedArm(
        inner, lambda topic, payload: recorded.append((topic, payload)), RealClock(), JobPosition()
    )

    async def reads() -> None:
        await arm.read_joints()
        with joint_reader(TELEMETRY_READER):
            await arm.read_joints()
        await arm.read_joints()  # (the block is over: the job's again)
        inner.unplugged = True
        for reader in (TELEMETRY_READER, JOB_READER):
            with joint_reader(reader), pytest.raises(BusLost):
                await arm.read_joints()

    asyncio.run(reads())
    topics = [topic for topic, _ in recorded]
    assert topics == ["input/joints"] * 3 + ["input/joints_failed"] * 2
    readers = [getattr(payload, "reader", None) for _, payload in recorded]
    assert readers == [JOB_READER, TELEMETRY_READER, JOB_READER, TELEMETRY_READER, JOB_READER]
    assert all(isinstance(p, InputJoints | ReadFailed) for _, p in recorded)


@pytest.mark.slow
def test_a_recorded_job_says_who_read_each_sample_and_its_replay_serves_the_job_its_own(
    two_mug_job: Path,
) -> None:
    session = RecordedSession.load(two_mug_job)
    samples = [r.message for r in session.streams["input/joints"]]
    assert all(isinstance(m, InputJoints) for m in samples)
    readers = Counter(m.reader for m in samples if isinstance(m, InputJoints))
    assert set(readers) == {JOB_READER, TELEMETRY_READER}
    # The telemetry polls at its rate over the whole session; the job reads where its work starts from the
    # arm (a plan, a retry, a rejoined move): far fewer.
    rate = session.config.daemon.joints_rate_hz
    assert readers[TELEMETRY_READER] >= 0.9 * rate * session.trace.duration_s
    assert 1 <= readers[JOB_READER] < readers[TELEMETRY_READER] / 10
    job_reads = len(Replayer(session, RealClock())._job_reads)
    assert job_reads == readers[JOB_READER]  # (all of them after the job's start)
    report = replay(session)
    assert report.match
    # Every read of the replay's job was served from the recording, in order, and the telemetry's too.
    assert report.served["input/joints"] >= job_reads
