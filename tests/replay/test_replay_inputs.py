"""A replay's inputs are checked before it starts, and a replay ends cleanly: a recording with a damaged
header is one line and exit 2 (never a traceback or a hang), ``--record`` is checked before the replay runs, a
killed replay's working directory does not outlive it, shutdown does not raise, and the trace is what the
daemon did, not what its recording kept."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cli.main import main
from daemon.zenoh_session import ZenohSession
from recorder import read_messages
from replay.engine import ReplayOptions, replay, sweep_stale_replay_dirs
from replay.faults import FaultInjector, parse_faults
from replay.session import RecordedSession
from tests.replay.conftest import copy_recording
from tests.replay.faulty import run_with_faults
from tests.replay.test_run_faults_cli import without_logs


def replay_error(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    capsys.readouterr()
    code = main(["replay", *argv])
    return code, without_logs(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("clock", "message"),
    [
        (
            {"source": "simulated", "wall_start": 1e11},
            "the session header's clock.wall_start 1e+11 is out of range; allowed [946684800, 4102444800] "
            "(2000-2100, seconds since 1970)",
        ),
        (
            {"source": "simulated", "wall_start": -5e9},
            "the session header's clock.wall_start -5e+09 is out of range; allowed [946684800, 4102444800] "
            "(2000-2100, seconds since 1970)",
        ),
        (
            {"source": "simulated"},
            "the session header's clock.wall_start is missing; a simulated session's clock needs its "
            "wall-clock start (seconds since 1970)",
        ),
        (
            {"source": "simulated", "wall_start": "noon"},
            "the session header's clock.wall_start is 'noon'; a simulated session's clock needs its "
            "wall-clock start (seconds since 1970)",
        ),
    ],
)
def test_a_recording_with_a_bad_clock_in_its_header_is_one_line_and_exit_2(
    two_mug_job: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    clock: dict[str, object],
    message: str,
) -> None:
    forged = copy_recording(two_mug_job, tmp_path / "forged-job.mcap", lambda _t, p: p, clock=clock)
    code, err = replay_error(capsys, str(forged))
    assert (code, err) == (2, f"dishbot replay: error: {forged}: {message}\n")


def test_record_is_checked_before_the_replay_starts(
    two_mug_job: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    existing = tmp_path / "taken.mcap"
    existing.write_bytes(b"")
    # The session does not even exist: --record is refused first, before anything is read or run.
    code, err = replay_error(capsys, str(tmp_path / "nope-job.mcap"), "--record", str(existing))
    assert (code, err) == (
        2,
        f"dishbot replay: error: --record {existing}: the file exists; choose a new name\n",
    )
    not_a_dir = tmp_path / "file.txt"
    not_a_dir.write_text("x")
    target = not_a_dir / "out.mcap"
    code, err = replay_error(capsys, str(two_mug_job), "--record", str(target))
    assert (code, err) == (2, f"dishbot replay: error: --record {target}: {not_a_dir} is not a directory\n")


@pytest.mark.slow
def test_the_working_directory_of_a_killed_replay_is_swept_and_a_stopped_one_cleans_up(
    two_mug_job: Path, tmp_path: Path
) -> None:
    env = {**os.environ, "TMPDIR": str(tmp_path)}

    def start() -> tuple[subprocess.Popen[bytes], Path]:
        proc = subprocess.Popen(
            [sys.executable, "-m", "cli.main", "replay", str(two_mug_job), "--speed", "1"],
            cwd=Path(__file__).resolve().parents[2],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for _ in range(1200):  # the directory appears once the replay runs (bounded: 10 minutes)
            found = list(tmp_path.glob(f"dishbot-replay-{proc.pid}-*"))
            if found:
                return proc, found[0]
            assert proc.poll() is None, "the replay ended before it started"
            time.sleep(0.5)
        proc.kill()
        raise AssertionError("the replay never made its working directory")

    proc, work = start()
    proc.kill()
    proc.wait()
    assert work.is_dir()  # SIGKILL: nothing in the process could clean up
    mine = tmp_path / f"dishbot-replay-{os.getpid()}-live"
    mine.mkdir()
    sweep_stale_replay_dirs(tmp_path)
    assert not work.exists()
    assert mine.is_dir()  # a running replay's directory is left alone

    proc, work = start()
    proc.send_signal(signal.SIGTERM)
    # Stopped in the daemon (its report, or "started no job" when that was before the job), or before it.
    assert proc.wait(timeout=600) in (0, 2, 128 + signal.SIGTERM)
    assert not work.exists()


def test_publishing_after_the_session_closed_is_recorded_only_and_closing_twice_is_harmless() -> None:
    session = ZenohSession.open("t", listen=[], connect=[], max_command_bytes=65536)
    written: list[str] = []

    class Sink:
        def write(self, topic: str, payload: object, *, log_time_ns: int, data: bytes | None = None) -> None:
            written.append(topic)

    session.attach_recorder(Sink(), lambda: 0)  # type: ignore[arg-type]
    session.close()
    session.publish("events", {"kind": "recording_failed"})  # the recorder's last word, after shutdown
    session.close()
    assert written == ["dishbot/t/events"]


@pytest.mark.slow
def test_a_disk_full_replay_reports_what_the_daemon_did_not_what_its_recording_kept(
    two_mug_job: Path, tmp_path: Path
) -> None:
    session = RecordedSession.load(two_mug_job)
    faults = FaultInjector(
        parse_faults(
            '[[fault]]\nkind = "disk_full"\nat_state = "side_grasp.approach"\nduration_s = 5\n',
            source="faults.toml",
        )
    )
    kept = tmp_path / "kept.mcap"
    report = replay(session, ReplayOptions(record=kept), faults=faults)
    assert report.replayed.final_state == "done"
    kinds = [e.kind for e in report.replayed.events]
    assert "recording_failed" in kinds
    assert report.replay_duration_s == pytest.approx(session.trace.duration_s, rel=0.2)
    assert [o.fired for o in report.fault_outcomes] == [True]
    # The kept recording lost what was written while the disk was full: the report did not.
    kept_transitions = [
        m for m in read_messages(kept) if m.topic.endswith("/events") and m.payload["kind"] == "transition"
    ]
    assert len(kept_transitions) < len(report.replayed.states)


@pytest.mark.slow
def test_a_disk_full_replay_writes_the_recording_nobody_keeps_so_that_the_fault_acts(
    one_mug_job: Path,
) -> None:
    """A replay writes no recording nobody keeps, unless a fault acts on it: the full disk must meet the
    recorder's writes for the daemon to see them fail."""
    session = RecordedSession.load(one_mug_job)
    faults = FaultInjector(
        parse_faults('[[fault]]\nkind = "disk_full"\nat_state = "detect"\nduration_s = 5\n', source="f.toml")
    )
    assert faults.acts_on_recording
    report = replay(session, ReplayOptions(), faults=faults)
    assert report.recording is None
    assert [o.fired for o in report.fault_outcomes] == [True]
    kinds = [e.kind for e in report.replayed.events]
    # Failed at the full disk, and restored at the first write once there is room: without writes, the
    # daemon would never learn the disk had room again.
    assert kinds.index("recording_failed") < kinds.index("recording_restored")
    slip = FaultInjector(
        parse_faults('[[fault]]\nkind = "mug_slip"\nat_state = "flip.transit"\n', source="f.toml")
    )
    assert not slip.acts_on_recording


@pytest.mark.slow
@pytest.mark.parametrize(
    "fault",
    [
        'kind = "servo_silent"\nservo = 3\nat_state = "detect"\nduration_s = 30\n',
        'kind = "bus_unplug"\nat_state = "detect"\nduration_s = 30\n',
    ],
)
def test_a_daemon_whose_servo_is_gone_at_shutdown_still_shuts_down_cleanly(
    tmp_path: Path, fault: str
) -> None:
    """The job faults at once and the daemon stops while the servo is still silent (or the adapter still
    pulled): the arm cannot be relaxed, which is logged, and shutdown goes on to its end."""
    run = run_with_faults(tmp_path, f"[[fault]]\n{fault}", world="mujoco", mugs=1)
    assert run.result.end_state == "fault"
    assert [o.fired for o in run.injector.outcomes()] == [True]
