"""A daemon killed with SIGKILL mid-session leaves a recording that reads back up to about a second ago."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from recorder import read_messages

RATE_HZ = 200

WRITER = textwrap.dedent(
    f"""
    import sys, time
    from pathlib import Path
    from recorder import Recorder

    rec = Recorder(Path(sys.argv[1]), chunk_size=65536)
    rec.write_header({{"robot_id": "r1"}}, {{"dataset": 3}}, log_time_ns=time.time_ns())
    start = time.monotonic()
    i = 0
    while True:
        rec.write("dishbot/r1/input/force", {{"i": i, "force_n": 0.5}}, log_time_ns=time.time_ns())
        if i % 10 == 0:
            print(f"sent {{i}}", flush=True)
        i += 1
        time.sleep(max(0.0, start + i / {RATE_HZ} - time.monotonic()))
    """
)


@pytest.mark.slow
def test_sigkilled_writer_loses_at_most_about_a_second(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    last_sent = run_and_kill(WRITER, path)
    rec = read_messages(path)
    assert rec.truncated
    assert not rec.being_written  # its writer is gone: cut by a crash
    assert rec.header == {"config": {"robot_id": "r1"}, "scene": {"dataset": 3}}
    recovered = [m.payload["i"] for m in rec if m.topic == "dishbot/r1/input/force"]
    assert recovered == list(range(len(recovered)))
    assert len(recovered) - 1 >= last_sent - RATE_HZ * 1.0
    assert rec.cut_after_ns == rec.end_ns


FOXGLOVE_WRITER = textwrap.dedent(
    f"""
    import sys, time
    from pathlib import Path
    from daemon.config import load_config
    from daemon.backend import scene_view
    from recorder import Recorder

    rec = Recorder(Path(sys.argv[1]), chunk_size=65536, deriver=scene_view(load_config()))
    rec.write_header({{"robot_id": "r1"}}, {{}}, log_time_ns=time.time_ns())
    names = ["shoulder_turn", "shoulder_lift", "elbow_lift", "wrist_lift", "wrist_turn"]
    start = time.monotonic()
    i = 0
    while True:
        q = [0.001 * i, -0.8, 1.6, 0.4, -1.57]
        sample = {{"t": i, "names": names, "position_rad": q}}
        rec.write("dishbot/r1/joints", sample, log_time_ns=time.time_ns())
        if i % 10 == 0:
            print(f"sent {{i}}", flush=True)
        i += 1
        time.sleep(max(0.0, start + i / {RATE_HZ} - time.monotonic()))
    """
)


@pytest.mark.slow
def test_sigkilled_writer_keeps_the_foxglove_channels_to_the_same_bound(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    last_sent = run_and_kill(FOXGLOVE_WRITER, path)
    rec = read_messages(path)
    assert rec.truncated
    joints = [m.payload["t"] for m in rec if m.topic == "dishbot/r1/joints"]
    assert joints == list(range(len(joints)))
    assert len(joints) - 1 >= last_sent - RATE_HZ * 1.0
    # Every recovered sample's transforms are in the file too (one /tf per sample, plus the opening one).
    assert len(joints) <= rec.topic_counts["/tf"] - 1 <= len(joints) + 1
    assert rec.topic_counts["/scene/arm"] == 1


def run_and_kill(script: str, path: Path) -> int:
    """Run a writer script for 1.6 s after its first message, SIGKILL it; the last message number it sent."""
    proc = subprocess.Popen(
        [sys.executable, "-c", script, str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.stdout is not None
    last_sent = -1
    started: float | None = None
    try:
        for line in proc.stdout:
            if not line.startswith("sent "):
                continue
            last_sent = int(line.split()[1])
            started = started or time.monotonic()
            if time.monotonic() - started > 1.6:
                break
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    return last_sent


FULL_DISK = textwrap.dedent(
    """
    import json, resource, signal, sys
    from pathlib import Path
    from recorder import Recorder

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG instead
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
    rec = Recorder(Path(sys.argv[1]), chunk_size=2048)
    accepted = sum(rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i) for i in range(3000))
    stats = rec.close()
    print(json.dumps({"accepted": accepted, "written": stats.written, "dropped": stats.dropped,
                      "failure": repr(rec.failure)}))
    """
)


@pytest.mark.slow
def test_a_full_disk_counts_the_lost_messages_and_leaves_a_readable_file(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    result = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(path)], capture_output=True, text=True, timeout=60, check=True
    )
    report = json.loads(result.stdout.splitlines()[-1])
    assert "File too large" in report["failure"]
    assert report["written"] + report["dropped"] == 3000
    assert report["dropped"] > 0
    rec = read_messages(path)
    assert rec.truncated
    assert path.stat().st_size <= 20_000
    recovered = [m.payload["i"] for m in rec]
    assert recovered == list(range(len(recovered)))
    assert 0 < report["written"] <= len(recovered) <= report["written"] + report["dropped"]
