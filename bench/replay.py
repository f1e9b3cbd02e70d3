"""``dishbot bench replay``: record simulated jobs, replay each without faults, and say whether every trace
matched and how fast the replays ran against the recorded duration.

The sessions (default ``5,3,2``): kinematic jobs of datasets 1-5, MuJoCo jobs of datasets 1-3 (in-process,
simulated time), and jobs of the MuJoCo cell on pseudo-terminals: the real Dynamixel and FSR drivers
talking to the device simulators through the kernel's serial layer on the wall clock, the robot's code path
to the bytes, with two mugs each so that they take about a minute of wall time. Recording is not timed;
the replay's wall time is. Targets: every replay matches, >= 20x real time for a kinematic session and
>= 10x for a MuJoCo one (issue 20). A faithful replay is served its motion and placement plans from the
recording (``served_motion``: the plans handed to the job), so what it costs is the daemon's own work and
the cell's moves. ``replay_cpu_s`` is the replay's process CPU time (every thread), ``x_cpu_time`` the
recorded duration over it: on a shared machine the wall time says as much about the other jobs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import structlog

from cli.commands.output import add_json_flag, emit
from cli.progress import Progress
from daemon.errors import UsageError

log = structlog.get_logger("bench.replay")

# Two mugs for the sessions on pseudo-terminals (wall-clock time): a big and a small one, each flipped.
PTY_MUGS = (("m1", "small", 0.22, 0.415), ("m2", "big", 0.064, 0.415))
TARGETS = {"kinematic": 20.0, "mujoco": 10.0, "mujoco-pty": 10.0}


@dataclass(frozen=True, slots=True)
class Session:
    kind: str  # kinematic, mujoco, mujoco-pty
    dataset: int | None  # None: PTY_MUGS


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "replay",
        help="record simulated jobs, replay them without faults: traces matched and replay speed",
        description=(
            "Record K kinematic, M MuJoCo and P MuJoCo-on-pseudo-terminal jobs (--sessions K,M,P, "
            "default 5,3,2), replay each without faults (dishbot replay) and print per session whether "
            "the trace matched, the recorded duration, the replay's wall time and their ratio. Targets: "
            "every replay matches; >= 20x real time for kinematic sessions, >= 10x for MuJoCo ones."
        ),
    )
    parser.add_argument(
        "--sessions",
        default="5,3,2",
        metavar="K,M,P",
        help="kinematic, MuJoCo and MuJoCo-on-pseudo-terminal sessions (default 5,3,2)",
    )
    parser.add_argument("--seed", type=int, default=0, help="detection noise seed of the recorded jobs")
    add_json_flag(parser)
    parser.set_defaults(handler=run)


def sessions(text: str) -> list[Session]:
    try:
        k, m, p = (int(v) for v in text.split(","))
    except ValueError as e:
        raise UsageError(f"--sessions {text!r}: give three counts K,M,P, e.g. 5,3,2") from e
    if not (0 <= k <= 6 and 0 <= m <= 3 and 0 <= p <= 5) or k + m + p == 0:
        raise UsageError(f"--sessions {text!r}: K is 0-6 (datasets), M 0-3, P 0-5, not all 0")
    return (
        [Session("kinematic", n) for n in range(1, k + 1)]
        + [Session("mujoco", n) for n in range(1, m + 1)]
        + [Session("mujoco-pty", None) for _ in range(p)]
    )


def run(args: argparse.Namespace) -> int:
    from replay.engine import replay
    from replay.record import record_job
    from replay.session import RecordedSession

    planned = sessions(args.sessions)
    rows = []
    with tempfile.TemporaryDirectory(prefix="dishbot-bench-replay-") as tmp:
        progress = Progress("bench replay", len(planned), enabled=not args.json)
        for i, s in enumerate(planned):
            progress.next(f"{s.kind}, {f'dataset {s.dataset}' if s.dataset is not None else '2 mugs'}")
            world = "kinematic" if s.kind == "kinematic" else "mujoco"
            log.info("recording", session=i + 1, of=len(planned), kind=s.kind, dataset=s.dataset)
            job = record_job(
                Path(tmp) / f"s{i}",
                world=world,
                dataset=s.dataset or 1,
                seed=args.seed,
                mugs=PTY_MUGS if s.dataset is None else None,
                transport="pty" if s.kind == "mujoco-pty" else "inprocess",
            )
            log.info("replaying", session=i + 1, of=len(planned))
            cpu_start = time.process_time()
            report = replay(RecordedSession.load(job.path))
            cpu_s = time.process_time() - cpu_start
            ratio = report.recorded_duration_s / report.wall_s if report.wall_s > 0 else 0.0
            d = report.first_divergence
            rows.append(
                [
                    s.kind,
                    s.dataset if s.dataset is not None else "2 mugs",
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
                ]
            )
    columns = [
        "session",
        "dataset",
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
    ]
    matched = sum(1 for r in rows if r[4])
    extra: dict[str, object] = {
        "matched": f"{matched} of {len(rows)}",
        "all_matched": matched == len(rows),
        "target x_real_time": "kinematic >= 20, mujoco >= 10",
    }
    emit("bench replay: fault-free replays of recorded jobs", columns, rows, as_json=args.json, extra=extra)
    return 0
