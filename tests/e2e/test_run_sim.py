"""End to end: ``dishbot run --sim`` as a subprocess, commanded and followed over loopback Zenoh.

The test starts the daemon on a free port, waits for it to answer, subscribes to ``state``, starts a job on
two mugs of dataset 1, follows ``state`` until the job is done with the planned mugs placed, sends SIGTERM,
and checks that the process exits 0 and that its MCAP recording holds the same sequence of states the
subscriber saw.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh

from daemon.zenoh_session import session_config
from recorder import read_messages
from tests.daemon.conftest import free_port
from tests.fakes.counter import dataset_mugs

ROBOT = "e2e"
SPEED = 60.0
STARTED_S = 120.0  # wall-clock limits against a hang only: a loaded machine is slow
JOB_S = 600.0


def _dedupe(states: list[str]) -> list[str]:
    return [s for i, s in enumerate(states) if i == 0 or states[i - 1] != s]


def _query(session: zenoh.Session, verb: str, body: dict[str, Any] | None = None) -> dict[str, Any] | None:
    payload = json.dumps(body).encode() if body else b""
    # A reply ends the query at once; the timeout only bounds a daemon that does not answer (generous: a
    # loaded machine's daemon answered a start after more than 2 s).
    for reply in session.get(f"dishbot/{ROBOT}/cmd/{verb}", payload=payload, timeout=10.0):
        if reply.ok is not None:
            result: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
            return result
    return None


@pytest.mark.slow
def test_run_sim_places_the_planned_mugs_and_records_what_it_published(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = tmp_path / "robot.toml"
    config.write_text(f'robot_id = "{ROBOT}"\n[planner]\nmethod = "bh"\n')
    record_dir = tmp_path / "recordings"
    cmd = [sys.executable, "-m", "cli.main", "run", "--sim", "--world", "kinematic", "--dataset", "1"]
    cmd += [
        "--speed",
        str(SPEED),
        "--listen",
        endpoint,
        "--record-dir",
        str(record_dir),
        "--config",
        str(config),
    ]
    log = (tmp_path / "daemon.log").open("w")
    daemon = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=Path(__file__).parents[2])
    seen: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_state(sample: zenoh.Sample) -> None:
        with lock:
            seen.append(json.loads(sample.payload.to_bytes()))

    try:
        with zenoh.open(session_config(listen=[], connect=[endpoint])) as session:
            # Generous wall-clock limits: they only keep a hang from running on (a daemon's start and a
            # four-mug job at load 16-20 on two cores took over 40 s); the states are the property.
            deadline = time.monotonic() + STARTED_S
            status = None
            while status is None and time.monotonic() < deadline and daemon.poll() is None:
                status = _query(session, "status")
                time.sleep(0.1)
            assert status is not None, (tmp_path / "daemon.log").read_text()
            assert status["state"] == "idle"
            subscriber = session.declare_subscriber(f"dishbot/{ROBOT}/state", on_state)
            while not seen and time.monotonic() < deadline:
                time.sleep(0.05)
            assert _query(session, "start", {"mugs": dataset_mugs(2), "planner": {"method": "bh"}}) == {
                "robot_id": ROBOT,
                "ok": True,
                "state": "detect",
            }
            deadline = time.monotonic() + JOB_S
            while time.monotonic() < deadline:
                with lock:
                    last = seen[-1]
                if last["state"] == "done":
                    break
                time.sleep(0.05)
            final = _query(session, "status")
            del subscriber
        assert final is not None
        assert final["state"] == "done", (tmp_path / "daemon.log").read_text()[-3000:]
        assert final["mugs_placed"] >= 1
        assert final["mugs_placed"] == final["summary"]["placed"]
        assert final["mugs_placed"] + final["mugs_failed"] >= final["mugs_planned"]
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(timeout=STARTED_S) == 0
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()
        log.close()

    # An idle file until the start, the job's file, and an idle file again after the job's tail.
    recordings = sorted(record_dir.glob("*.mcap"))
    assert [p.name.rsplit("-", 1)[1] for p in recordings][:2] == ["idle.mcap", "job.mcap"]
    reads = [read_messages(p) for p in recordings]
    assert not any(r.truncated for r in reads)
    assert all(r.header is not None for r in reads)
    job = reads[1].header
    assert job is not None
    assert [m["id"] for m in job["job"]["mugs"]] == [m["id"] for m in dataset_mugs(2)]  # type: ignore[index]
    recorded = [str(m.payload["state"]) for r in reads for m in r if m.topic == f"dishbot/{ROBOT}/state"]
    with lock:
        subscribed = [str(s["state"]) for s in seen]
    recorded_seq = _dedupe(recorded)
    subscribed_seq = _dedupe(subscribed)
    assert subscribed_seq[0] == "idle"
    assert (
        recorded_seq[recorded_seq.index("detect") - 1 :]
        == subscribed_seq[subscribed_seq.index("detect") - 1 :]
    )
    assert recorded_seq[-1] == "done"
    assert {"detect", "plan", "side_grasp.approach", "flip.turn", "place.release"} <= set(recorded_seq)
    topics = set(reads[1].topic_counts)
    assert {"/tf", "/scene/arm", "/scene/cell", "/scene/mugs", "/scene/plan", "/log", "/events"} <= topics
    for topic in ("state", "joints", "gripper", "detections", "plan", "events", "log"):
        assert f"dishbot/{ROBOT}/{topic}" in topics
    for topic in ("input/observation", "input/grasp", "input/holding", "input/joints", "input/force"):
        assert f"dishbot/{ROBOT}/{topic}" in topics
