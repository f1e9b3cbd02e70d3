"""A whole recorded job, key by key: every message a kinematic dataset-1 job (seed 3) records has a shape (its
keys, in order, at every depth) that the same job recorded before the producers built the declared structs
had (``tests/data/kinematic-ds1-shapes.json``, made with ``python -m tests.daemon.test_wire_golden FILE`` from
a recording of ``dishbot run --sim --world kinematic --once --dataset 1 --seed 3`` on the earlier code), and
every topic it had. Log records are left out: a record is whatever its call named."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import pytest

from recorder import read_messages
from tests.fakes.daemon import loopback
from wire.schemas import topic_suffix

GOLDEN = Path(__file__).parent.parent / "data" / "kinematic-ds1-shapes.json"
OPEN = frozenset({"log"})


def shape(value: object) -> str:
    """The keys of a JSON value in their order, at every depth (a list: its elements' distinct shapes)."""
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{shape(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        seen: list[str] = []
        for item in value:
            s = shape(item)
            if s not in seen:
                seen.append(s)
        return "[" + "|".join(seen) + "]"
    return ""


def shapes(path: Path) -> dict[str, list[str]]:
    """Each topic's distinct message shapes, in the order they first came."""
    out: dict[str, list[str]] = {}
    for m in read_messages(path):
        topic = topic_suffix(m.topic)
        if topic in OPEN or m.topic.startswith("/"):  # Foxglove's derived views are not the wire contract
            continue
        known = out.setdefault(topic, [])
        s = shape(m.payload)
        if s not in known:
            known.append(s)
    return out


def _recording(directory: Path) -> Path:
    files: Iterable[Path] = sorted(directory.glob("*.mcap"))
    [path] = files
    return path


@pytest.mark.slow
def test_a_recorded_job_has_the_shapes_it_had_before(tmp_path: Path) -> None:
    argv = [
        *("run", "--sim", "--world", "kinematic", "--once", "--dataset", "1", "--seed", "3"),
        *("--record-dir", str(tmp_path), "--listen", loopback()),
    ]
    done = subprocess.run(
        [sys.executable, "-m", "cli.main", *argv], capture_output=True, text=True, timeout=900, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    golden: dict[str, list[str]] = json.loads(GOLDEN.read_text())
    now = shapes(_recording(tmp_path))
    assert sorted(now) == sorted(golden)
    for topic, seen in now.items():
        new = [s for s in seen if s not in golden[topic]]
        assert not new, f"{topic}: shapes the earlier code never wrote: {new}"


if __name__ == "__main__":  # the golden file from a recording made on the earlier code
    print(json.dumps(shapes(Path(sys.argv[1])), indent=1, sort_keys=True))
