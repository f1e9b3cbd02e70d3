"""While a replay follows its recording, its telemetry hands on the gripper as the recording's telemetry
read it (``RecordedSession.gripper``), rather than reading the stand-in's gripper over its bus (issue 22:
a tenth of a kinematic replay's CPU); the job never reads the gripper, so the trace is the same."""

from __future__ import annotations

import array
from pathlib import Path

import pytest

from replay.engine import ReplayOptions, replay
from replay.session import RecordedSession
from tests.replay.conftest import copy_recording
from wire.messages import Gripper, topic_suffix

# What the copy adds to every recorded gripper opening: the stand-in's own gripper never says so.
_SHIFT_M = 0.00123


def _job_grippers(path: Path) -> list[tuple[float, float, float]]:
    """The ``gripper`` telemetry of the job in ``path`` (strictly between its start and its end): device
    time, opening, load."""
    session = RecordedSession.load(path)
    end_ns = session.start_ns + round(session.trace.duration_s * 1e9)
    out = []
    for m in session.read.messages:
        g = m.decoded(Gripper) if topic_suffix(m.topic) == "gripper" else None
        if g is not None and session.start_ns < m.log_time_ns < end_ns:
            out.append((float(g.t_device), float(g.aperture_m), float(g.load)))  # type: ignore[arg-type]
    return out


def _shifted(suffix: str, payload: dict[str, object]) -> dict[str, object]:
    if suffix == "gripper":
        aperture = payload["aperture_m"]
        assert isinstance(aperture, float)
        return {**payload, "aperture_m": round(aperture + _SHIFT_M, 5)}
    return payload


@pytest.mark.slow  # records a job and replays it
def test_a_replays_gripper_telemetry_is_the_recorded_one_while_it_follows_the_recording(
    one_mug_job: Path, tmp_path: Path
) -> None:
    shifted = copy_recording(one_mug_job, tmp_path / "shifted-job.mcap", _shifted)
    session = RecordedSession.load(shifted)
    assert isinstance(session.gripper.read_times, array.array)
    assert len(session.gripper.read_times) > 100  # (50 Hz over the job)
    report = replay(session, ReplayOptions(record=tmp_path / "again.mcap"))
    assert report.match
    recorded, replayed = _job_grippers(shifted), _job_grippers(tmp_path / "again.mcap")
    assert len(replayed) == len(recorded) > 100
    for (t, aperture, load), (t_rec, aperture_rec, load_rec) in zip(replayed, recorded, strict=True):
        assert t == pytest.approx(t_rec, abs=1e-9)
        assert (aperture, load) == (aperture_rec, load_rec)
