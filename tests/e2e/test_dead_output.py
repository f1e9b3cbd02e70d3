"""End to end: a broken stdout/stderr never changes what ``dishbot run`` does.

``dishbot run --sim --once --world kinematic 2>&1 | head -n 3`` runs its job to the end it would have had
and exits with its recording finished; ``dishbot run ... | tee log`` and Ctrl-C (tee dies first, the
daemon goes on writing to a closed pipe), or systemd's SIGTERM, exits within the unit's ``TimeoutStopSec``
with the recording finished. The time bounds here only catch a hang (they are the unit's contract, far
above what a stop takes); the seconds are printed for the record.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO

import pytest

from recorder import read_messages
from tests.daemon.conftest import free_port
from tests.fakes.counter import mugs_file

TIMEOUT_STOP_S = 45.0  # systemd/dishbot.service: TimeoutStopSec
JOB_HANG_S = 600.0  # far above a kinematic dataset-1 job on a loaded machine: only a hang gets there


def _start(tmp_path: Path, *extra: str) -> subprocess.Popen[bytes]:
    """``dishbot run --sim --world kinematic`` with stdout and stderr on one pipe (``2>&1 | ...``)."""
    cmd = [sys.executable, "-B", "-m", "cli.main", "run", "--sim", "--world", "kinematic", *extra]
    cmd += ["--record-dir", str(tmp_path), "--listen", f"tcp/127.0.0.1:{free_port()}"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def _read_until(out: IO[bytes], text: bytes) -> list[bytes]:
    lines = []
    for line in out:
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f"the output ended before {text!r}: {b''.join(lines[-20:]).decode()}")


def _job_file(tmp_path: Path) -> Path:
    (job,) = [p for p in tmp_path.iterdir() if p.name.endswith("-job.mcap")]
    return job


def _end_state(path: Path) -> str:
    recorded = read_messages(path)
    assert not recorded.truncated, f"{path.name} was not finished"
    ends = [
        m.payload["dest"]
        for m in recorded
        if m.topic.endswith("/events") and m.payload.get("kind") == "transition"
    ]
    return str(ends[-1])


@pytest.mark.slow
def test_a_once_job_whose_output_reader_left_after_3_lines_runs_to_its_end_and_exits(tmp_path: Path) -> None:
    # Two mugs: the reader leaves at the first lines, long before the job ends.
    daemon = _start(tmp_path, "--once", "--mugs", str(mugs_file(tmp_path, 2)))
    assert daemon.stdout is not None
    for _ in range(3):  # `| head -n 3`
        daemon.stdout.readline()
    daemon.stdout.close()
    started = time.monotonic()
    daemon.wait(timeout=JOB_HANG_S)
    print(f"exited {time.monotonic() - started:.1f} s after its reader left, code {daemon.returncode}")
    assert _end_state(_job_file(tmp_path)) == "done"  # as without the pipe: nothing stalled, nothing crashed
    recorded = read_messages(_job_file(tmp_path))
    stopped = [
        m.payload for m in recorded if m.topic.endswith("/log") and m.payload["event"] == "daemon_stopped"
    ]
    assert len(stopped) == 1
    lost = stopped[0]["log_lines_lost"]
    assert isinstance(lost, int)
    assert lost > 0


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_stop_signal_mid_job_with_a_dead_output_exits_in_time_with_the_recording_finished(
    tmp_path: Path, sig: signal.Signals
) -> None:
    daemon = _start(tmp_path, "--once")
    assert daemon.stdout is not None
    _read_until(daemon.stdout, b"cycle_planned")  # the job is under way
    daemon.stdout.close()  # `| tee log` died first (Ctrl-C reaches the whole pipeline)
    time.sleep(0.5)  # the daemon goes on, writing to the dead pipe
    assert daemon.poll() is None
    os.kill(daemon.pid, sig)
    sent = time.monotonic()
    try:
        daemon.wait(timeout=TIMEOUT_STOP_S)
    finally:
        took = time.monotonic() - sent
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()
    print(f"{sig.name}: exited {took:.2f} s after the signal, code {daemon.returncode}")
    assert took < TIMEOUT_STOP_S
    recorded = read_messages(_job_file(tmp_path))
    assert not recorded.truncated  # finished: summary and footer written
    assert [m for m in recorded if m.topic.endswith("/log") and m.payload["event"] == "daemon_stopped"] != []
