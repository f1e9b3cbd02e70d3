"""``dishbot replay`` end to end: a recorded simulated job run again through the real daemon on simulated
time reproduces its trace; a recording of something else is noticed where it first differs, and the
simulated cell carries the job on from there; a cut recording replays up to the cut; bad input is one line
and exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main
from recorder import Recorder, read_messages
from replay.engine import ReplayOptions, replay
from replay.session import RecordedSession
from tests.replay.conftest import copy_recording


@pytest.mark.slow
def test_a_kinematic_job_replays_exactly_from_its_recording(two_mug_job: Path, tmp_path: Path) -> None:
    session = RecordedSession.load(two_mug_job)
    report = replay(session, ReplayOptions(record=tmp_path / "again.mcap"))
    assert report.first_divergence is None
    assert report.match
    assert report.replayed.states == session.trace.states
    # Simulated time: the same instants (to the microsecond the header keeps the clock's wall start to).
    assert report.replayed.state_times_s == pytest.approx(session.trace.state_times_s, abs=1e-6)
    assert [e.kind for e in report.replayed.events] == [e.kind for e in session.trace.events]
    assert report.replayed.final_state == "done"
    # The recorded inputs were what the job saw: every kind of them was served.
    assert {"observation", "plan", "follow", "grasp", "input/joints", "input/holding"} <= set(report.served)
    # The replay's own recording is a recording like any other, and replays again.
    again = RecordedSession.load(tmp_path / "again.mcap")
    assert again.trace.states == session.trace.states


@pytest.mark.slow
def test_a_different_observation_diverges_at_the_plan_and_the_simulated_cell_finishes_the_job(
    three_mug_job: Path, tmp_path: Path
) -> None:
    """The recording says the camera saw one mug fewer at first: the daemon plans for the mugs it was given,
    the plan differs from the recorded one, and from there the simulated cell (which has all three mugs)
    carries on. (Of two mugs, the one planned alone took the other's place: a job of three places them
    all.)"""
    seen = {"first": True}

    def one_mug_fewer(topic: str, payload: dict[str, object]) -> dict[str, object]:
        if topic == "input/observation" and seen["first"]:
            seen["first"] = False
            mugs = payload["mugs"]
            assert isinstance(mugs, list)
            return {**payload, "mugs": mugs[1:]}
        return payload

    changed = copy_recording(three_mug_job, tmp_path / "changed-job.mcap", one_mug_fewer)
    report = replay(RecordedSession.load(changed))
    assert not report.match
    d = report.first_divergence
    assert d is not None
    # In the plan state: the arm's check plans a cycle for the changed counter first (``motion``), or the
    # placement plan differs (``plan``).
    assert d.state == "plan"
    assert d.what in ("motion", "plan")
    assert d.t_s == 0.0
    assert report.served["observation"] == 1  # the changed one; the simulated cell's after
    assert report.replayed.final_state == "done"
    placed = [e for e in report.replayed.events if e.kind == "mug_placed"]
    assert len(placed) == 3


# Times of one simulated instant taken from two wall-clock timestamps (see below).
_SAME_INSTANT_S = 1e-6


@pytest.mark.parametrize("fraction", [0.3, 0.5, 0.8])
@pytest.mark.slow
def test_a_recording_cut_by_a_crash_replays_up_to_the_cut_and_says_so(
    fraction: float, two_mug_job: Path, tmp_path: Path
) -> None:
    whole = RecordedSession.load(two_mug_job)
    data = two_mug_job.read_bytes()
    cut = tmp_path / "cut-job.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    session = RecordedSession.load(cut)
    assert session.cut is not None
    report = replay(session)
    assert report.cut == session.cut
    assert report.match, report.first_divergence
    # The replay stopped just after the recording does (a second later), in the state the whole job was in
    # then. Its last state began at the same simulated instant as the whole job's: the two times are sums
    # of a wall-clock start (about 1.7e9 s, a new one per recording) and simulated time, equal only to the
    # float's resolution there (2.4e-7 s), so "then" is just after that instant (it used to be read at the
    # instant itself, and one recording in three or so, by its start, found the state before).
    assert 0 < len(report.replayed.states) < len(whole.trace.states)
    assert len(report.replayed.states) >= len(session.trace.states)
    last = report.replayed.state_times_s[-1]
    recorded_last = whole.trace.state_times_s[len(report.replayed.states) - 1]
    assert last == pytest.approx(recorded_last, abs=_SAME_INSTANT_S)
    assert report.replayed.final_state == whole.trace.state_at(last + _SAME_INSTANT_S)
    assert report.replayed.states == whole.trace.states[: len(report.replayed.states)]


@pytest.mark.slow
def test_replay_json_has_the_documented_fields_and_check_passes(
    two_mug_job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--log-level", "warning", "replay", str(two_mug_job), "--json", "--check"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["match"] is True
    assert doc["first_divergence"] is None
    assert doc["final_state"] == "done"
    assert doc["states"][0] == "detect"
    assert doc["states"][-1] == "done"
    assert all(isinstance(s, str) for s in doc["states"])
    assert all("kind" in e for e in doc["events"])
    assert doc["faults"] == []
    assert doc["recorded_duration_s"] > 10
    assert doc["wall_s"] > 0


@pytest.mark.slow
def test_check_exits_1_when_a_replay_without_faults_does_not_match(
    two_mug_job: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def lost_grasp(topic: str, payload: dict[str, object]) -> dict[str, object]:
        if topic == "input/grasp":
            return {**payload, "held": False, "reason": "force stayed below the threshold"}
        return payload

    changed = copy_recording(two_mug_job, tmp_path / "lost-job.mcap", lost_grasp)
    assert main(["--log-level", "warning", "replay", str(changed), "--check"]) == 1
    out = capsys.readouterr().out
    assert "diverged at" in out


def _foreign_mcap(path: Path) -> Path:
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("x", "jsonschema", b"{}")
        channel = w.register_channel("/other", "json", schema)
        w.add_message(channel, log_time=1, data=b"{}", publish_time=1)
        w.finish()  # type: ignore[no-untyped-call]
    return path


def _idle_file(path: Path) -> Path:
    with Recorder(path) as rec:
        rec.write_header(
            {"robot_id": "r"}, {"backend": "sim-kinematic"}, log_time_ns=1, file={"kind": "idle"}
        )
    return path


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda p: p / "missing.mcap", "no such file"),
        (lambda p: (p / "text.mcap").write_text("hello") and p / "text.mcap", "not an MCAP file"),
        (lambda p: _foreign_mcap(p / "foreign.mcap"), "not a dishbot recording"),
        (lambda p: _idle_file(p / "idle.mcap"), "holds no job"),
    ],
    ids=["missing", "not-mcap", "foreign", "idle"],
)
def test_a_file_that_is_not_a_job_recording_is_one_line_and_exit_2(
    make: object, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = make(tmp_path)  # type: ignore[operator]
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith("dishbot replay: error:")
    assert needle in err


@pytest.mark.parametrize(
    ("flags", "needle"),
    [
        (["--speed", "fast"], "--speed"),
        (["--speed", "0"], "--speed"),
        (["--listen", "udp/nowhere"], "--listen"),
    ],
)
def test_bad_flags_are_one_line_and_exit_2(
    flags: list[str], needle: str, two_mug_job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["replay", str(two_mug_job), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert needle in err


def test_record_to_an_existing_file_is_refused_and_the_file_is_kept(
    two_mug_job: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    existing = tmp_path / "keep.mcap"
    existing.write_bytes(b"mine")
    assert main(["replay", str(two_mug_job), "--record", str(existing)]) == 2
    assert "exists" in capsys.readouterr().err
    assert existing.read_bytes() == b"mine"


def test_the_replay_verb_is_on_the_command_line_with_help() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "cli.main", "replay", "--help"], capture_output=True, text=True, check=True
    ).stdout
    for flag in ("--faults", "--speed", "--record", "--listen", "--json", "--check"):
        assert flag in out


def test_the_recording_keeps_what_a_replay_needs(two_mug_job: Path) -> None:
    read = read_messages(two_mug_job)
    topics = {m.topic.split("/", 2)[-1] for m in read.messages}
    assert {
        "input/joints",
        "input/force",
        "input/holding",
        "input/grasp",
        "input/observation",
        "plan",
    } <= topics
    assert {"output/follow", "output/gripper"} <= topics
    header = read.header
    assert header is not None
    job = header["job"]
    assert isinstance(job, dict)
    assert job["sim_seed"] == 0
    assert job["planner"]["seed"] == 0
    follow = next(m.payload for m in read.messages if m.topic.endswith("output/follow"))
    assert {"label", "end_rad", "t_start", "t_end", "duration_s"} <= set(follow)


@pytest.mark.slow
def test_with_listen_the_replay_publishes_on_zenoh_as_the_daemon_does(two_mug_job: Path) -> None:
    """A monitor connected to ``--listen`` sees the replayed job's state, joints and events, as from a
    daemon (the replay runs at 20x real time so that the subscriber is there before the job ends)."""
    import threading
    import time

    import zenoh

    from daemon.zenoh_session import session_config
    from tests.daemon.conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    seen: dict[str, int] = {}
    stop = threading.Event()

    def monitor() -> None:
        deadline = time.monotonic() + 10.0
        while not stop.is_set() and time.monotonic() < deadline:
            try:
                with zenoh.open(session_config(listen=[], connect=[endpoint])) as z:
                    z.declare_subscriber(
                        "dishbot/*/**", lambda s: seen.__setitem__(str(s.key_expr).rsplit("/", 1)[-1], 1)
                    )
                    stop.wait(10.0)
                    return
            except zenoh.ZError:
                time.sleep(0.1)  # the replay's daemon is not listening yet

    watcher = threading.Thread(target=monitor)
    watcher.start()
    try:
        report = replay(RecordedSession.load(two_mug_job), ReplayOptions(speed=20.0, listen=(endpoint,)))
    finally:
        stop.set()
        watcher.join()
    assert report.match
    assert {"state", "joints", "events"} <= set(seen)
