"""``dishbot replay SESSION.mcap``: run a recorded job again through the daemon, with faults if asked, and
say whether it did what the recording says."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cli.commands.output import add_json_flag
from daemon.config import check_endpoint
from daemon.errors import ConfigError, UsageError
from replay.errors import ReplayError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "replay",
        help="re-run a recorded job through the daemon on simulated time, with injected faults",
        description=(
            "Re-run the job a recording holds (a -job.mcap file of `dishbot run`, on the robot or a "
            "simulated cell) through the real daemon: the job, the statechart, the planners and the "
            "recorder, on simulated time, with a simulated stand-in cell. The recorded inputs (joint "
            "feedback, force, grasp results, observations, plans, the operator's commands) stand in for the "
            "cell's while the daemon does what it did then; from the first difference, or the first "
            "injected fault, the stand-in is set to the world the recording saw at that instant (mugs, arm, "
            "gripper) and carries on alone: model-based from there. Prints whether the trace matched or "
            "where it first diverged, from when the world was re-simulated, the faults fired, every fault "
            "of the file that did not fire and why, the final state and the events. Exit 0 when the "
            "replay ran (with --check: 1 when a replay without faults did not match, or a fault of the "
            "file did not fire), 2 for bad input. See docs/recording.md."
        ),
    )
    parser.add_argument("session", type=Path, metavar="SESSION.mcap", help="a job recording")
    parser.add_argument(
        "--faults",
        type=Path,
        metavar="FAULTS.toml",
        help="inject the faults of this file ([[fault]] tables; docs/recording.md)",
    )
    parser.add_argument(
        "--speed",
        metavar="X",
        default="max",
        help="simulated seconds per wall second (0.1-1000), or max: as fast as the machine allows (default)",
    )
    parser.add_argument(
        "--record", type=Path, metavar="OUT.mcap", help="keep the replay's own recording here"
    )
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="publish on Zenoh while replaying, e.g. tcp/127.0.0.1:3474 (repeatable; default: no endpoint)",
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="allow a plain --listen endpoint that other machines can reach",
    )
    parser.add_argument(
        "--resim",
        choices=("kinematic", "mujoco"),
        help="the stand-in world to re-simulate in after a divergence or fault (default: the recording's "
        "own simulated world; kinematic for a robot's recording)",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="exit 1 when a replay without faults does not match the recording, or a fault did not fire",
    )
    add_json_flag(parser)
    parser.set_defaults(handler=_replay)


def _replay(args: argparse.Namespace) -> int:
    from daemon.clock import parse_speed
    from replay.engine import ReplayOptions, check_record_path, replay
    from replay.session import RecordedSession

    try:
        speed = parse_speed(args.speed)
    except ValueError as e:
        raise UsageError(f"--speed {e}") from e
    try:
        listen = tuple(check_endpoint(e, "--listen") for e in args.listen or ())
    except ConfigError as e:
        raise UsageError(str(e)) from e
    try:
        if args.record is not None:
            check_record_path(args.record)  # before a long replay, not after it
        session = RecordedSession.load(args.session)
    except ReplayError as e:
        raise UsageError(str(e)) from e
    injector = None
    if args.faults is not None:
        from replay.faults import FaultInjector, load_fault_file

        specs = load_fault_file(args.faults, config=session.config)
        if any(s.kind == "disk_full" for s in specs) and args.record is None:
            raise UsageError(
                f"{args.faults}: disk_full acts on the replay's own recording; add --record OUT.mcap"
            )
        injector = FaultInjector(specs)
    options = ReplayOptions(
        speed=speed, record=args.record, listen=listen, insecure=args.insecure, resim=args.resim
    )
    try:
        report = replay(session, options, faults=injector)
    except ReplayError as e:
        raise UsageError(str(e)) from e
    if args.json:
        json.dump(report.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        sys.stdout.write("\n".join(report.lines()) + "\n")
    if args.check and (report.unfired or (args.faults is None and not report.match)):
        return 1
    return 0
