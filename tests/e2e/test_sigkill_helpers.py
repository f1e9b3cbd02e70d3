"""A ``kill -9`` of the daemon mid-job leaves none of its helper processes running: the multiprocessing
forkserver, the planning worker it forked and the resource tracker end with it (``daemon.lifeline``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from cli.commands.client import request
from tests.daemon.conftest import free_port


@dataclass(frozen=True, slots=True)
class _Proc:
    pid: int
    state: str  # R, S, Z (exited, not reaped yet), ...
    ppid: int
    session: int
    cmdline: str


def _processes() -> list[_Proc]:
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # gone meanwhile
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        out.append(_Proc(int(entry.name), fields[0], int(fields[1]), int(fields[3]), cmdline))
    return out


def _in_session(sid: int) -> list[_Proc]:
    """The processes of a session, the daemon's descendants (re-parented to PID 1 or not), alive or zombie."""
    return [p for p in _processes() if p.session == sid]


def _alive(sid: int) -> list[_Proc]:
    return [p for p in _in_session(sid) if p.state != "Z"]


def _helpers(pid: int, forkservers: int, within_s: float) -> list[_Proc]:
    """The live descendants of the process ``pid`` (a session leader) once at least ``forkservers`` of them
    run a forkserver (the server and the workers it forked), or as they are after ``within_s``."""
    deadline = time.monotonic() + within_s
    helpers: list[_Proc] = []
    while time.monotonic() < deadline:
        helpers = [p for p in _alive(pid) if p.pid != pid]
        if sum("forkserver" in p.cmdline for p in helpers) >= forkservers:
            break
        time.sleep(0.1)
    return helpers


def _kill_and_wait(proc: subprocess.Popen[str] | subprocess.Popen[bytes]) -> float:
    """SIGKILL ``proc`` and give its descendants 10 s to end; the seconds they took (10 when some did not)."""
    os.kill(proc.pid, signal.SIGKILL)
    killed = time.monotonic()
    proc.wait(timeout=10)
    while _alive(proc.pid) and time.monotonic() - killed < 10.0:
        time.sleep(0.05)
    return time.monotonic() - killed


def _reap(proc: subprocess.Popen[str] | subprocess.Popen[bytes]) -> None:
    """Whatever the test's outcome, leave neither ``proc`` nor its descendants behind on the machine."""
    if proc.poll() is None:
        proc.kill()
        proc.wait(timeout=10)
    for p in _alive(proc.pid):
        os.kill(p.pid, signal.SIGKILL)


@pytest.mark.slow
def test_sigkill_mid_job_leaves_no_helper_process_alive(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = ["run", "--sim", "--world", "kinematic", "--listen", endpoint, "--record-dir", str(tmp_path)]
    daemon = subprocess.Popen(
        [sys.executable, "-m", "cli.main", *run, "--speed", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # the session id marks its descendants, wherever they are re-parented
    )
    try:
        assert daemon.stdout is not None
        for line in daemon.stdout:
            if "daemon_ready" in line:
                break
        reply = request(endpoint, "dishbot", "start", {}, timeout_s=20.0)  # answered at once; generous
        assert reply is not None
        assert reply["ok"], reply
        helpers = _helpers(daemon.pid, 2, within_s=30.0)  # the forkserver and its worker
        assert sum("forkserver import main" in p.cmdline for p in helpers) == 2, helpers
        assert sum("resource_tracker" in p.cmdline for p in helpers) == 1, helpers
        print(f"helpers gone {_kill_and_wait(daemon):.3f} s after the kill")
        assert _alive(daemon.pid) == []
    finally:
        _reap(daemon)  # without the fix: do not leave them behind on the machine


@pytest.mark.slow
def test_sigkill_of_a_bench_with_worker_processes_leaves_none_of_them_alive() -> None:
    """``bench placement --layouts N --jobs 2`` checks layouts in worker processes forked by the forkserver:
    killed with SIGKILL, it takes them and the forkserver along (they used to keep running to the end)."""
    # Two dataset-1 layouts, one per worker: the bench draws them in a fraction of a second (six of
    # dataset 4 took it over 4 CPU-s before any worker started), and each keeps its worker busy for seconds.
    bench = ["bench", "placement", "--layouts", "2", "--datasets", "1", "--jobs", "2", "--no-unchecked"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", *bench],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        helpers = _helpers(proc.pid, 3, within_s=60.0)  # the forkserver and two workers
        assert proc.poll() is None, "the bench ended before its workers were seen"
        assert sum("forkserver" in p.cmdline for p in helpers) >= 3, helpers
        _kill_and_wait(proc)
        assert _alive(proc.pid) == []
    finally:
        _reap(proc)  # without the fix: do not leave them behind on the machine
