"""A daemon killed with SIGKILL mid-session leaves a recording that reads back up to about a second ago."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from daemon.recording import read_messages

RATE_HZ = 200

WRITER = textwrap.dedent(
    f"""
    import sys, time
    from pathlib import Path
    from daemon.recording import Recorder

    rec = Recorder(Path(sys.argv[1]), chunk_size=65536)
    rec.write_header({{"robot_id": "r1"}}, {{"dataset": 3}})
    start = time.monotonic()
    i = 0
    while True:
        rec.write("dishbot/r1/driver/force", {{"i": i, "force_n": 0.5}}, log_time_ns=time.time_ns())
        if i % 10 == 0:
            print(f"sent {{i}}", flush=True)
        i += 1
        time.sleep(max(0.0, start + i / {RATE_HZ} - time.monotonic()))
    """
)


def test_sigkilled_writer_loses_at_most_about_a_second(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path)],
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
    rec = read_messages(path)
    assert rec.truncated
    assert rec.header == {"config": {"robot_id": "r1"}, "scene": {"dataset": 3}}
    recovered = [m.payload["i"] for m in rec if m.topic == "dishbot/r1/driver/force"]
    assert recovered == list(range(len(recovered)))
    assert len(recovered) - 1 >= last_sent - RATE_HZ * 1.0
    assert rec.cut_after_ns == rec.end_ns
