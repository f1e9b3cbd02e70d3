"""``dishbot bench replay --memory``: how much memory a replay takes against the length of its recording.

Records two kinematic jobs of dataset 1 (simulated time, so cheaply): an ordinary one, and the same job
paused by the operator in its first ``flip.transit`` for ``--paused-s`` simulated seconds (default 3360,
making a job file of about an hour: while paused the drivers go on being read and the daemon goes on
publishing, as on the robot), then resumed to its end. With ``--memory-mujoco`` an ordinary MuJoCo job of
dataset 1 is added. Each job file is loaded and replayed (``RecordedSession.load``, ``replay.engine.replay``)
in a fresh Python process, which reports its resident memory after the load and its peak (the kernel's
``VmHWM``) at the end: the figures are the process's own, not a timing. Target (issue 22): the replay of a
1-hour recording peaks at <= 600 MB.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import structlog

from cli.commands.output import emit
from cli.progress import Progress
from daemon.errors import UsageError

log = structlog.get_logger("bench.replay")

TARGET_PEAK_MB: Final = 600.0  # a 1-hour recording's replay (issue 22)
PAUSED_S_DEFAULT: Final = 3360.0  # with the ordinary ds1 job's ~240 s: a job file of about an hour
PAUSED_S_RANGE: Final = (1.0, 4 * 3600.0)
PAUSE_IN: Final = "flip.transit"
# How long the measuring process may take (a guard against a hang, not a measurement).
_CHILD_TIMEOUT_S: Final = 3600.0

# What the measuring process runs: only ``RecordedSession.load`` and ``replay``, so that the same text
# measures another checkout's code too (``python -c`` in its tree: a before/after comparison).
CHILD: Final = """
import json, sys
from pathlib import Path

def status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0

base = status("VmRSS")
from replay.engine import replay
from replay.session import RecordedSession
imported = status("VmRSS")
session = RecordedSession.load(Path(sys.argv[1]))
loaded = status("VmRSS")
report = replay(session)
print(json.dumps({
    "rss_start": base, "rss_imported": imported, "rss_loaded": loaded, "peak": status("VmHWM"),
    "match": report.match, "final_state": report.replayed.final_state,
    "recorded_s": report.recorded_duration_s, "wall_s": report.wall_s,
}))
"""


@dataclass(frozen=True, slots=True)
class MemoryCase:
    label: str
    world: str
    paused_s: float  # 0: an ordinary job


@dataclass(frozen=True, slots=True)
class Measured:
    """What the measuring process reported for one job file (bytes, seconds)."""

    rss_imported: int
    rss_loaded: int
    peak: int
    match: bool
    final_state: str
    recorded_s: float
    wall_s: float


def check_paused_s(value: float) -> float:
    low, high = PAUSED_S_RANGE
    if not low <= value <= high:
        raise UsageError(f"--paused-s {value:g} is out of range; allowed [{low:g}, {high:g}]")
    return value


def cases(paused_s: float, *, mujoco: bool) -> list[MemoryCase]:
    out = [
        MemoryCase("kinematic ds1", "kinematic", 0.0),
        MemoryCase(f"kinematic ds1, paused {paused_s:g} s", "kinematic", paused_s),
    ]
    if mujoco:
        out.append(MemoryCase("mujoco ds1", "mujoco", 0.0))
    return out


def record_paused_job(directory: Path, *, world: str, paused_s: float, seed: int = 0) -> Path:
    """A dataset 1 job on the simulated ``world``, paused by the operator ``paused_s`` simulated seconds in
    its first ``flip.transit`` (0: not paused) and then resumed to its end; the job file. Blocking."""
    from daemon.app import ServeContext, ServeHooks
    from replay.record import record_job
    from wire.messages import reply_of

    def operator(ctx: ServeContext) -> None:
        async def go() -> None:
            while ctx.job is None or ctx.job.chart.state != PAUSE_IN:
                await ctx.clock.sleep(0.01)
            if reply_of(await ctx.handle("pause", b"", False)).ok is not True:
                raise RuntimeError("the job refused the operator's pause")
            await ctx.clock.sleep(paused_s)
            if reply_of(await ctx.handle("resume", b"", False)).ok is not True:
                raise RuntimeError("the job refused the operator's resume")

        asyncio.get_running_loop().create_task(go())

    hooks = ServeHooks(on_ready=operator) if paused_s > 0 else None
    return record_job(directory, world=world, dataset=1, seed=seed, hooks=hooks).path


def measure(path: Path, *, python: str = sys.executable, cwd: Path | None = None) -> Measured:
    """Load and replay ``path`` in a fresh process (``python``, run in ``cwd``); what it reported."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    done = subprocess.run(
        [python, "-c", CHILD, str(path)],
        capture_output=True,
        text=True,
        timeout=_CHILD_TIMEOUT_S,
        cwd=cwd,
        env=env,
        check=False,
    )
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"replaying {path.name} failed (exit {done.returncode}): {tail}")
    doc = json.loads(lines[-1])
    return Measured(
        rss_imported=int(doc["rss_imported"]),
        rss_loaded=int(doc["rss_loaded"]),
        peak=int(doc["peak"]),
        match=bool(doc["match"]),
        final_state=str(doc["final_state"]),
        recorded_s=float(doc["recorded_s"]),
        wall_s=float(doc["wall_s"]),
    )


def run_memory(*, paused_s: float, mujoco: bool, keep: Path | None, as_json: bool) -> int:
    planned = cases(check_paused_s(paused_s), mujoco=mujoco)
    rows = []
    with tempfile.TemporaryDirectory(prefix="dishbot-bench-replay-memory-") as tmp:
        base = keep if keep is not None else Path(tmp)
        progress = Progress("bench replay --memory", len(planned), unit="session", enabled=not as_json)
        for i, case in enumerate(planned):
            progress.next(case.label)
            log.info("recording", session=i + 1, of=len(planned), label=case.label)
            path = record_paused_job(
                base / f"m{i + 1:02d}-{case.world}", world=case.world, paused_s=case.paused_s
            )
            log.info("replaying", session=i + 1, of=len(planned))
            m = measure(path)
            rows.append(
                [
                    case.label,
                    round(m.recorded_s, 1),
                    round(path.stat().st_size / 1e6, 1),
                    m.match,
                    _mb(m.rss_imported),
                    _mb(m.rss_loaded),
                    _mb(m.rss_loaded - m.rss_imported),
                    _mb(m.peak),
                    m.peak / 1e6 <= TARGET_PEAK_MB,
                    round(m.wall_s, 1),
                    str(path) if keep is not None else "",
                ]
            )
    columns = [
        "session",
        "recorded_s",
        "file_mb",
        "match",
        "rss_after_imports_mb",
        "rss_after_load_mb",
        "load_mb",
        "peak_rss_mb",
        "peak_under_600_mb",
        "replay_wall_s",
        "job_file",
    ]
    extra: dict[str, object] = {
        "target": f"peak RSS <= {TARGET_PEAK_MB:.0f} MB replaying a 1-hour recording",
        "all_matched": all(r[3] for r in rows),
    }
    emit(
        "bench replay --memory: a replay's memory against its recording",
        columns,
        rows,
        as_json=as_json,
        extra=extra,
    )
    return 0


def _mb(n: int) -> float:
    return round(n / 1e6, 1)
