"""``dishbot bench replay``: record jobs, replay each without faults, and say whether every trace matched
and how fast the replays ran against the recorded duration.

The simulated sessions (``--sessions K,M,P``, default ``5,3,2``): kinematic jobs of datasets 1-5, MuJoCo
jobs of datasets 1-3 (in-process, simulated time), and jobs of the MuJoCo cell on pseudo-terminals: the
real Dynamixel and FSR drivers talking to the device simulators through the kernel's serial layer on the
wall clock, with two mugs each.

The robot's recordings (``--rig N``): N jobs recorded as the robot records them, through the robot rig
without a robot. Each starts ``dishbot sim rig`` (alternately ``--world mujoco`` and ``--world
kinematic``) with a counter of two or three mugs taken from one of the datasets 1-5 (``--mugs``, a new pick
and depth-noise ``--seed`` each), then ``dishbot run --config FILE --once`` on the config it wrote,
recording: the hardware backend, the real drivers on the rig's pseudo-terminals, the depth frames over
Zenoh, perception, on the wall clock (about a minute a job). Each job file is then replayed with
``dishbot replay``'s engine. With ``--rig`` only the rig's sessions run unless ``--sessions`` is given too.

Recording is not timed; the replay's wall time is. Targets (issue 20): every replay matches; >= 20x real
time for a kinematic session and >= 10x for a MuJoCo or a rig one. A faithful replay is served its motion
and placement plans from the recording (``served_motion``, ``served_placement``: the plans handed to the
job), so what it costs is the daemon's own work and the stand-in's moves. ``replay_cpu_s`` is the replay's
process CPU time (every thread), ``x_cpu_time`` the recorded duration over it: on a shared machine the
wall time says as much about the other jobs.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import structlog

from cli.commands.output import add_json_flag, emit
from cli.progress import Progress
from daemon.errors import UsageError

log = structlog.get_logger("bench.replay")

# Two mugs for the sessions on pseudo-terminals (wall-clock time): a big and a small one, each flipped.
PTY_MUGS = (("m1", "small", 0.22, 0.415), ("m2", "big", 0.064, 0.415))
TARGETS: Final = {
    "kinematic": 20.0,
    "mujoco": 10.0,
    "mujoco-pty": 10.0,
    "rig-mujoco": 10.0,
    "rig-kinematic": 10.0,
}
RIG_MAX: Final = 20
# The rig sessions' mugs stand in the datasets' two front rows, right of x = -0.26 m (world frame).
_NEAR: Final = (-0.26, 0.53)
# Guards against a hang, not measurements: a rig job of three mugs takes about 80 s of wall time.
_RIG_READY_S: Final = 180.0
_RIG_JOB_S: Final = 900.0
_RIG_STOP_S: Final = 60.0
_RIG_ATTEMPTS: Final = 2


@dataclass(frozen=True, slots=True)
class Session:
    kind: str  # kinematic, mujoco, mujoco-pty, rig-mujoco, rig-kinematic
    dataset: int | None  # None: PTY_MUGS
    seed: int = 0
    mugs: tuple[tuple[str, str, float, float], ...] = ()  # a rig session's counter

    @property
    def label(self) -> str:
        if self.kind.startswith("rig-"):
            return f"ds{self.dataset}: {' '.join(m[0] for m in self.mugs)}, seed {self.seed}"
        return f"dataset {self.dataset}" if self.dataset is not None else "2 mugs"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "replay",
        help="record jobs (simulated, or through the robot rig), replay them without faults: traces matched "
        "and replay speed",
        description=(
            "Record K kinematic, M MuJoCo and P MuJoCo-on-pseudo-terminal jobs (--sessions K,M,P, "
            "default 5,3,2) and N jobs through the robot rig without a robot (--rig N: `dishbot sim rig` "
            "with --world mujoco and kinematic in turn, two or three mugs of datasets 1-5, then `dishbot "
            "run --config FILE --once` recording, on the wall clock, about a minute each), replay each "
            "without faults (dishbot replay) and print per session whether the trace matched, the first "
            "divergence, the recorded duration, the replay's wall time and their ratio, and the plans "
            "served. Targets: every replay matches; >= 20x real time for kinematic sessions, >= 10x for "
            "MuJoCo and rig ones."
        ),
    )
    parser.add_argument(
        "--sessions",
        default=None,
        metavar="K,M,P",
        help="kinematic, MuJoCo and MuJoCo-on-pseudo-terminal sessions (default 5,3,2; 0,0,0 with --rig)",
    )
    parser.add_argument(
        "--rig",
        type=int,
        default=0,
        metavar="N",
        help=f"also record N jobs through `dishbot sim rig` and replay them (0-{RIG_MAX}; default 0)",
    )
    parser.add_argument("--seed", type=int, default=0, help="detection noise seed of the recorded jobs")
    parser.add_argument(
        "--keep",
        metavar="DIR",
        help="keep the recorded job files in DIR (a new or empty folder; default: a temporary one)",
    )
    parser.add_argument(
        "--memory",
        action="store_true",
        help="measure memory instead: record an ordinary kinematic dataset 1 job and the same job paused by "
        "the operator for --paused-s (about an hour of recording), replay each in a fresh process and "
        "report its peak resident memory against the recording's size and duration (target: <= 600 MB "
        "for the hour)",
    )
    parser.add_argument(
        "--paused-s",
        type=float,
        default=None,
        metavar="S",
        help="with --memory: how long the operator pauses the long job, simulated seconds (default 3360: "
        "a job file of about an hour)",
    )
    parser.add_argument(
        "--memory-mujoco",
        action="store_true",
        help="with --memory: also an ordinary MuJoCo dataset 1 job",
    )
    add_json_flag(parser)
    parser.set_defaults(handler=run)


def sessions(text: str) -> list[Session]:
    try:
        k, m, p = (int(v) for v in text.split(","))
    except ValueError as e:
        raise UsageError(f"--sessions {text!r}: give three counts K,M,P, e.g. 5,3,2") from e
    if not (0 <= k <= 6 and 0 <= m <= 3 and 0 <= p <= 5):
        raise UsageError(f"--sessions {text!r}: K is 0-6 (datasets), M 0-3, P 0-5")
    return (
        [Session("kinematic", n) for n in range(1, k + 1)]
        + [Session("mujoco", n) for n in range(1, m + 1)]
        + [Session("mujoco-pty", None) for _ in range(p)]
    )


def _started_up() -> None:
    """What a process pays once, not a replay: the simulated cells' modules imported, and what the imports
    allocated kept out of the cyclic collector's scans (the daemon's ``serve`` collects and freezes the heap
    as it starts; the first replay of a process paid 0.1-0.15 s of CPU for it, most of a short rig job's
    replay, and the others nothing)."""
    import daemon.sim_backend  # noqa: F401  (the stand-in cells)

    gc.collect()
    gc.freeze()


def rig_sessions(n: int) -> list[Session]:
    """``n`` rig sessions: the MuJoCo and the kinematic world in turn; session i takes two mugs (three
    every third session) of dataset ``1 + i % 5`` among those of its two front rows in easy reach of the
    arm (``_NEAR``), a different pick each session, and depth-noise seed i."""
    if not 0 <= n <= RIG_MAX:
        raise UsageError(f"--rig {n} is out of range; allowed [0, {RIG_MAX}]")
    from daemon.config import load_config
    from sim.counter import dataset_counter

    config = load_config()
    out = []
    for i in range(n):
        dataset = 1 + i % 5
        counter = dataset_counter(dataset, config.cell, config.mug_catalogue()).mugs
        x_min, y_max = _NEAR
        near = [m for m in counter if m.x_m >= x_min and m.y_m <= y_max]
        count = 3 if i % 3 == 2 else 2
        picked = sorted({(i + 3 * k) % len(near) for k in range(count)})
        mugs = tuple(
            (m.mug_id, m.spec.name, round(m.x_m, 4), round(m.y_m, 4)) for m in (near[j] for j in picked)
        )
        out.append(Session(("rig-mujoco", "rig-kinematic")[i % 2], dataset, seed=i, mugs=mugs))
    return out


def run(args: argparse.Namespace) -> int:
    if args.memory:
        return _run_memory(args)
    if args.paused_s is not None or args.memory_mujoco:
        raise UsageError("--paused-s and --memory-mujoco go with --memory")
    from replay.engine import replay
    from replay.session import RecordedSession

    _started_up()
    sessions_text = args.sessions if args.sessions is not None else ("0,0,0" if args.rig else "5,3,2")
    planned = sessions(sessions_text) + rig_sessions(args.rig)
    if not planned:
        raise UsageError("nothing to run: --sessions 0,0,0 and no --rig")
    keep = _keep_dir(args.keep)
    rows = []
    with tempfile.TemporaryDirectory(prefix="dishbot-bench-replay-") as tmp:
        base = keep if keep is not None else Path(tmp)
        progress = Progress("bench replay", len(planned), unit="session", enabled=not args.json)
        for i, s in enumerate(planned):
            progress.next(f"{s.kind}, {s.label}")
            log.info("recording", session=i + 1, of=len(planned), kind=s.kind, dataset=s.dataset)
            path = _record(s, base / f"s{i + 1:02d}-{s.kind}", seed=args.seed)
            log.info("replaying", session=i + 1, of=len(planned))
            cpu_start = time.process_time()
            report = replay(RecordedSession.load(path))
            cpu_s = time.process_time() - cpu_start
            ratio = report.recorded_duration_s / report.wall_s if report.wall_s > 0 else 0.0
            d = report.first_divergence
            rows.append(
                [
                    s.kind,
                    s.label,
                    report.recorded.final_state,
                    len(report.recorded.states),
                    report.match,
                    "" if d is None else d.line(),
                    round(report.recorded_duration_s, 1),
                    round(report.wall_s, 2),
                    round(ratio, 1),
                    ratio >= TARGETS[s.kind],
                    round(cpu_s, 2),
                    round(report.recorded_duration_s / cpu_s, 1) if cpu_s > 0 else None,
                    report.served.get("motion", 0),
                    report.served.get("plan", 0),
                    str(path) if keep is not None else "",
                ]
            )
    columns = [
        "session",
        "counter",
        "end_state",
        "states",
        "match",
        "divergence",
        "recorded_s",
        "replay_wall_s",
        "x_real_time",
        "speed_target_met",
        "replay_cpu_s",
        "x_cpu_time",
        "served_motion",
        "served_placement",
        "job_file",
    ]
    matched = sum(1 for r in rows if r[4])
    extra: dict[str, object] = {
        "matched": f"{matched} of {len(rows)}",
        "all_matched": matched == len(rows),
        "target x_real_time": "kinematic >= 20, mujoco and rig >= 10",
    }
    emit("bench replay: fault-free replays of recorded jobs", columns, rows, as_json=args.json, extra=extra)
    return 0


def _run_memory(args: argparse.Namespace) -> int:
    from bench.replay_memory import PAUSED_S_DEFAULT, run_memory

    if args.sessions is not None or args.rig:
        raise UsageError("--memory records its own jobs; leave out --sessions and --rig")
    paused_s = PAUSED_S_DEFAULT if args.paused_s is None else args.paused_s
    return run_memory(
        paused_s=paused_s, mujoco=args.memory_mujoco, keep=_keep_dir(args.keep), as_json=args.json
    )


class RigNotStarted(RuntimeError):
    """``dishbot run`` could not open the rig's devices and recorded nothing (on a loaded machine the rig's
    first answers can come late): the job is tried again, in a new folder, up to ``_RIG_ATTEMPTS`` times."""


def _keep_dir(text: str | None) -> Path | None:
    if text is None:
        return None
    path = Path(text)
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise UsageError(f"--keep {text}: exists and is not an empty folder; name a new one")
    path.mkdir(parents=True, exist_ok=True)
    return path


def _record(s: Session, directory: Path, *, seed: int) -> Path:
    if s.kind.startswith("rig-"):
        return _record_on_rig(s, directory)
    from replay.record import record_job

    world = "kinematic" if s.kind == "kinematic" else "mujoco"
    return record_job(
        directory,
        world=world,
        dataset=s.dataset or 1,
        seed=seed,
        mugs=PTY_MUGS if s.dataset is None else None,
        transport="pty" if s.kind == "mujoco-pty" else "inprocess",
    ).path


def _record_on_rig(s: Session, directory: Path) -> Path:
    world = s.kind.removeprefix("rig-")
    for attempt in range(1, _RIG_ATTEMPTS):
        try:
            return record_rig_job(directory / f"attempt{attempt}", world=world, mugs=s.mugs, seed=s.seed)
        except RigNotStarted as e:
            log.warning("rig_job_not_started", attempt=attempt, error=str(e))
    return record_rig_job(directory / f"attempt{_RIG_ATTEMPTS}", world=world, mugs=s.mugs, seed=s.seed)


def record_rig_job(
    directory: Path, *, world: str, mugs: Sequence[tuple[str, str, float, float]], seed: int = 0
) -> Path:
    """Record one job as the robot records it, through the robot rig without a robot: ``dishbot sim rig
    --world WORLD --mugs FILE --seed SEED`` in a process of its own, ``dishbot run --config FILE --once``
    recording in ``directory`` in another; the job file. Blocking, on the wall clock. ``RuntimeError``
    naming the log when either process fails."""
    directory.mkdir(parents=True, exist_ok=True)
    mug_file = directory / "mugs.json"
    mug_file.write_text(
        json.dumps([{"id": i, "type": t, "x_m": x, "y_m": y} for i, t, x, y in mugs]), encoding="utf-8"
    )
    config = directory / "rig" / "robot.toml"
    config.parent.mkdir(exist_ok=True)
    cli = [sys.executable, "-m", "cli.main", "--log-level", "warning"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    rig_log = directory / "rig.log"
    run_log = directory / "run.log"
    rig_command = [
        *cli,
        "sim",
        "rig",
        "--world",
        world,
        "--mugs",
        str(mug_file),
        "--seed",
        str(seed),
        "--listen",
        f"tcp/127.0.0.1:{_free_port()}",
        "--write-config",
        str(config),
    ]
    with _process(rig_command, rig_log, env) as rig:
        _wait_ready(rig, rig_log)
        with run_log.open("w", encoding="utf-8") as out:
            run = subprocess.run(
                [
                    *cli,
                    "run",
                    "--once",
                    "--config",
                    str(config),
                    "--record-dir",
                    str(directory / "recordings"),
                    "--listen",
                    f"tcp/127.0.0.1:{_free_port()}",
                ],
                stdout=out,
                stderr=subprocess.STDOUT,
                timeout=_RIG_JOB_S,
                env=env,
                check=False,
            )
        if run.returncode == 2 and not (directory / "recordings").is_dir():
            raise RigNotStarted(f"dishbot run could not start on the {world} rig; see {run_log}")
        if run.returncode not in (0, 1):  # 1: the job ended in fault; its recording replays too
            raise RuntimeError(f"dishbot run on the {world} rig exited {run.returncode}; see {run_log}")
    jobs = sorted((directory / "recordings").glob("*-job.mcap"))
    if not jobs:
        raise RuntimeError(f"dishbot run on the {world} rig recorded no job; see {run_log}")
    return jobs[-1]


@contextlib.contextmanager
def _process(command: list[str], log_path: Path, env: dict[str, str]) -> Iterator[subprocess.Popen[str]]:
    """``command`` running, its stderr in ``log_path``; stopped with SIGTERM (then killed) at the end."""
    with log_path.open("w", encoding="utf-8") as err:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=err, text=True, env=env)
        try:
            yield process
        finally:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=_RIG_STOP_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            if process.stdout is not None:
                process.stdout.close()


def _wait_ready(process: subprocess.Popen[str], log_path: Path) -> None:
    assert process.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(process.stdout, selectors.EVENT_READ)
        if not sel.select(_RIG_READY_S):
            raise RuntimeError(
                f"the rig did not say it was ready within {_RIG_READY_S:.0f} s; see {log_path}"
            )
    line = process.stdout.readline()
    if not line.startswith("rig ready"):
        raise RuntimeError(f"the rig did not start; see {log_path}")


def _free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
