"""A session's files: one per job, idle time in rotating, thinned files, each with its own header; retention
deletes the oldest recordings past the limits and never one being written."""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

import pytest

from daemon.config import load_config
from daemon.hardware import scene_view
from recorder import Recorder, read_messages
from recorder.files import Retention, SessionRecording, file_name, is_job_file
from recorder.settings import RecordingConfig

T0 = 1_790_000_000_000_000_000
SECOND = 1_000_000_000
ROBOT = "r1"


def settings(**changes: object) -> RecordingConfig:
    return replace(load_config().recording, **changes)  # type: ignore[arg-type]


def transition(trigger: str, source: str, dest: str) -> dict[str, object]:
    return {"kind": "transition", "state": dest, "t": 0.0, "trigger": trigger, "source": source, "dest": dest}


class Stream:
    """Feeds a SessionRecording as the daemon would: telemetry at 50 Hz, events when they happen."""

    def __init__(self, recording: SessionRecording) -> None:
        self.recording = recording
        self.t = T0
        self.scene: dict[str, object] = {"dataset": 1}

    def telemetry(self, seconds: float) -> None:
        for _ in range(round(seconds * 50)):
            self.t += SECOND // 50
            self.recording.write(
                f"dishbot/{ROBOT}/joints",
                {"t": 0.0, "names": ["shoulder_turn"], "position_rad": [0.1]},
                log_time_ns=self.t,
            )
            self.recording.write(
                f"dishbot/{ROBOT}/gripper",
                {"t": 0.0, "aperture_m": 0.1, "holding": False},
                log_time_ns=self.t,
            )

    def event(self, payload: dict[str, object]) -> None:
        self.t += 1000
        self.recording.write(f"dishbot/{ROBOT}/events", payload, log_time_ns=self.t)


def session(tmp_path: Path, **changes: object) -> tuple[SessionRecording, Stream]:
    holder: dict[str, object] = {"dataset": 1}
    recording = SessionRecording(
        settings(**changes), tmp_path, ROBOT, config={"robot_id": ROBOT}, scene=lambda: dict(holder)
    )
    stream = Stream(recording)
    stream.scene = holder
    return recording, stream


def topics(path: Path) -> dict[str, int]:
    return dict(read_messages(path).topic_counts)


def test_no_file_is_created_before_the_first_message(tmp_path: Path) -> None:
    recording, _ = session(tmp_path)
    assert recording.path is None
    assert recording.close() is None
    assert list(tmp_path.iterdir()) == []


def test_a_job_gets_its_own_file_between_idle_files(tmp_path: Path) -> None:
    recording, s = session(tmp_path, job_tail_s=1.0)
    s.telemetry(2.0)
    recording.expect_job({"dataset": 2, "mugs": None, "planner": {"method": "bh"}})
    s.scene["dataset"] = 2
    s.event(transition("start", "idle", "detect"))
    s.telemetry(3.0)
    s.event(transition("next", "place.retreat", "done"))
    s.telemetry(0.5)  # inside the tail: still the job's
    s.telemetry(1.0)  # past it: an idle file again
    recording.close()
    idle1, job, idle2 = files = recording.files()
    assert [is_job_file(p) for p in files] == [False, True, False]
    assert [p.name for p in files] == sorted(p.name for p in tmp_path.iterdir())
    assert job.name == file_name(ROBOT, "job", T0 + 100 * (SECOND // 50) + 1000)
    headers = [read_messages(p).header for p in files]
    assert [h["file"]["kind"] for h in headers] == ["idle", "job", "idle"]  # type: ignore[index]
    assert [h["file"]["previous"] for h in headers] == [None, idle1.name, job.name]  # type: ignore[index]
    assert headers[1]["job"] == {"dataset": 2, "mugs": None, "planner": {"method": "bh"}}  # type: ignore[index]
    assert headers[1]["scene"] == {"dataset": 2}  # type: ignore[index]
    assert "job" not in headers[2]  # type: ignore[operator]
    job_read = read_messages(job)
    events = [m.payload for m in job_read if m.topic.endswith("/events")]
    assert [(e["trigger"], e["dest"]) for e in events] == [("start", "detect"), ("next", "done")]
    # The job keeps the full rate: 3 s + the 1 s tail of 50 Hz samples, give or take the boundary.
    assert 195 <= job_read.topic_counts[f"dishbot/{ROBOT}/joints"] <= 201
    assert topics(idle2)[f"dishbot/{ROBOT}/joints"] == 1  # the idle rate again: 1 Hz for the last 0.5 s


def test_idle_files_keep_telemetry_at_the_idle_rate_and_everything_else(tmp_path: Path) -> None:
    recording, s = session(tmp_path, idle_telemetry_hz=2.0)
    s.telemetry(5.0)
    s.event({"kind": "warning", "state": "idle", "t": 0.0, "message": "hello"})
    recording.close()
    (idle,) = recording.files()
    counts = topics(idle)
    assert counts[f"dishbot/{ROBOT}/joints"] == 10
    assert counts[f"dishbot/{ROBOT}/gripper"] == 10
    assert counts[f"dishbot/{ROBOT}/events"] == 1
    stats = recording.recorder.stats()  # type: ignore[union-attr]
    assert stats.thinned == 2 * 250 - 20
    assert stats.dropped == 0


def test_idle_files_rotate_after_idle_file_s(tmp_path: Path) -> None:
    recording, s = session(tmp_path, idle_file_s=10.0)
    s.telemetry(25.0)
    recording.close()
    files = recording.files()
    assert len(files) == 3
    assert not any(is_job_file(p) for p in files)
    spans = [(r.start_ns, r.end_ns) for r in map(read_messages, files)]
    assert all(end - start < 10 * SECOND for start, end in spans)  # type: ignore[operator]


def test_a_once_job_opens_its_file_at_once_and_a_second_start_opens_another(tmp_path: Path) -> None:
    recording = SessionRecording(
        settings(job_tail_s=0.0),
        tmp_path,
        ROBOT,
        config={"robot_id": ROBOT},
        scene=lambda: {"dataset": 3},
        job={"dataset": None, "mugs": None},
    )
    s = Stream(recording)
    s.telemetry(0.2)
    s.event(transition("start", "idle", "detect"))
    s.telemetry(0.2)
    s.event(transition("estop", "detect", "estop"))
    s.telemetry(0.2)
    s.event(transition("reset", "estop", "idle"))
    s.event(transition("start", "idle", "detect"))
    recording.close()
    files = recording.files()
    assert [is_job_file(p) for p in files] == [True, False, True]
    first = read_messages(files[0]).header
    assert first["job"] == {"dataset": 3, "mugs": None}  # type: ignore[index]  # the scene's dataset
    assert read_messages(files[2]).header["job"] == {"dataset": 3}  # type: ignore[index]


def test_every_file_starts_with_the_scene_so_far(tmp_path: Path) -> None:
    config = load_config()
    holder: dict[str, object] = {"dataset": 1}
    recording = SessionRecording(
        settings(job_tail_s=0.0),
        tmp_path,
        ROBOT,
        config={"robot_id": ROBOT},
        scene=lambda: holder,
        deriver=scene_view(config),
    )
    s = Stream(recording)
    s.telemetry(0.5)
    s.event(transition("start", "idle", "detect"))
    s.telemetry(0.5)
    recording.close()
    for path in recording.files():
        counts = topics(path)
        for topic in ("/scene/arm", "/scene/cell", "/scene/mugs", "/scene/plan", "/scene/status"):
            assert counts[topic] == 1, (path.name, topic)
        assert counts["/tf"] >= 1


def test_a_name_already_taken_gets_a_number(tmp_path: Path) -> None:
    taken = tmp_path / file_name(ROBOT, "idle", T0 + SECOND // 50)
    taken.write_bytes(b"someone else's")
    recording, s = session(tmp_path)
    s.telemetry(0.1)
    recording.close()
    (path,) = recording.files()
    assert path == taken.with_name(taken.stem + "-1.mcap")
    assert taken.read_bytes() == b"someone else's"
    assert not is_job_file(path)
    assert is_job_file(path.with_name(file_name(ROBOT, "job", T0).replace(".mcap", "-2.mcap")))


def aged(path: Path, size: int, age_s: float) -> Path:
    path.write_bytes(b"\x00" * size)
    stamp = time.time() - age_s
    os.utime(path, (stamp, stamp))
    return path


def test_retention_deletes_the_oldest_files_past_the_size_limit(tmp_path: Path) -> None:
    old = [aged(tmp_path / f"{ROBOT}-{i}.mcap", 1000, 100.0 - i) for i in range(5)]
    other = aged(tmp_path / "someone-else.mcap", 5000, 1000.0)
    deleted = Retention(max_total_bytes=2500, max_age_s=0).apply(tmp_path, ROBOT, keep=old[0])
    assert deleted == old[1:4]
    assert sorted(tmp_path.iterdir()) == sorted([old[0], old[4], other])


def test_retention_deletes_files_past_the_age_limit_but_never_one_being_written(tmp_path: Path) -> None:
    old = aged(tmp_path / f"{ROBOT}-old.mcap", 10, 3 * 86400.0)
    young = aged(tmp_path / f"{ROBOT}-young.mcap", 10, 60.0)
    live_path = tmp_path / f"{ROBOT}-live.mcap"
    with Recorder(live_path) as live:
        stamp = time.time() - 5 * 86400.0
        os.utime(live_path, (stamp, stamp))
        deleted = Retention(max_total_bytes=0, max_age_s=86400.0).apply(tmp_path, ROBOT)
        assert deleted == [old]
        assert live.path.exists()
    assert young.exists()


def test_no_limits_delete_nothing(tmp_path: Path) -> None:
    f = aged(tmp_path / f"{ROBOT}-x.mcap", 10**6, 10 * 365 * 86400.0)
    assert Retention(0, 0).apply(tmp_path, ROBOT) == []
    assert f.exists()


def test_rotation_applies_retention_to_the_directory(tmp_path: Path) -> None:
    old = aged(tmp_path / f"{ROBOT}-20200101T000000.000Z-job.mcap", 10_000, 1000.0)
    recording, s = session(tmp_path, max_total_mb=0, max_age_days=0.001, job_tail_s=0.0)
    s.telemetry(0.2)
    s.event(transition("start", "idle", "detect"))
    s.telemetry(0.2)
    recording.close()
    assert not old.exists()  # deleted when the job's file opened (86 s is past 0.001 days)
    assert all(p.exists() for p in recording.files())


@pytest.mark.parametrize("changes", [{"max_total_mb": 0, "max_age_days": 0.0}])
def test_retention_from_the_config(changes: dict[str, object]) -> None:
    assert Retention.of(settings(**changes)) == Retention(0, 0.0)
    assert Retention.of(settings()) == Retention(5000 * 1_000_000, 30 * 86400.0)
