"""End to end: ``dishbot run --sim --once`` whose recording cannot grow past a few kilobytes (the file-size
limit of the process, as a full disk: every write past it fails) still finishes its job, exits 0, and its
summary says how many messages the recording lost."""

from __future__ import annotations

import re
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from recorder import read_messages
from tests.daemon.conftest import free_port
from tests.fakes.counter import mugs_file

LIMIT_BYTES = 60_000


def _limited() -> None:
    """In the child: writes past the limit fail with EFBIG (instead of SIGXFSZ killing the process)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT_BYTES, LIMIT_BYTES))


@pytest.mark.slow
def test_a_once_job_on_a_full_disk_ends_done_and_counts_the_lost_messages(tmp_path: Path) -> None:
    cmd = [sys.executable, "-B", "-m", "cli.main", "run", "--sim", "--world", "kinematic", "--once"]
    # Two mugs: the recording outgrows the limit within the first; the whole dataset only takes longer.
    cmd += ["--mugs", str(mugs_file(tmp_path, 2)), "--record-dir", str(tmp_path)]
    cmd += ["--listen", f"tcp/127.0.0.1:{free_port()}"]
    result = subprocess.run(
        cmd, capture_output=True, text=True, timeout=300, preexec_fn=_limited, check=False
    )
    out = result.stdout
    assert result.returncode == 0, out[-2000:] + result.stderr[-2000:]
    assert "job ended in state done\n" in out
    lost = re.search(r"^recording lost (\d+) messages \(the disk failed or was too slow\)$", out, re.M)
    assert lost is not None, out[-2000:]
    assert int(lost.group(1)) > 100
    assert "recording_failed" in result.stderr  # logged (and published on `events`: tests/daemon check it)
    job_file = next(p for p in tmp_path.iterdir() if p.name.endswith("-job.mcap"))
    assert job_file.stat().st_size <= LIMIT_BYTES
    assert read_messages(job_file).truncated  # readable up to where the disk filled
