"""``dishbot run``: the daemon. It waits in idle for ``start``; with ``--once`` it runs one job and exits."""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import multiprocessing
import os
import sys
from pathlib import Path

from daemon.app import RunOptions, RunResult, serve, tolerated_exposure
from daemon.backend import (
    Backend,
    ProcessMotionPlanner,
    check_cell_reachable,
    open_hardware_backend,
    open_sim_backend,
)
from daemon.config import Config, check_endpoint, load_config
from daemon.errors import ConfigError, UsageError
from daemon.job import Associate, StartRequest
from daemon.logs import configure_cli_logging
from daemon.sdnotify import SdNotifier
from description import thesis
from perception import associate
from planning.arm import ArmModel

_PLANNING_NICENESS = 10


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "run",
        help="run the daemon (simulated cell with --sim); --once runs one loading job and exits",
        description=(
            "Run the dishbot daemon: publish state, joints, gripper force, detections, plan, events and logs "
            "on Zenoh under dishbot/<robot_id>/, answer cmd/<verb> queries, record the session to MCAP. "
            "Without --once it waits in idle for a start command (dishbot start). SIGTERM or Ctrl-C stops "
            'motion safely, finishes the recording and exits 0. With the config\'s backend = "hardware" it '
            "drives the robot on the [hardware] ports (see docs/hardware.md); a missing port or camera "
            "package, a servo chain unlike the config or a cell the arm cannot reach exits 2 at once."
        ),
    )
    parser.add_argument(
        "--sim",
        action="store_true",
        help="run on the simulated cell even when the config's backend is hardware (default: config backend)",
    )
    parser.add_argument(
        "--world",
        choices=("kinematic", "mujoco"),
        help="simulated cell: the kinematic placeholder or the MuJoCo physics (default: config sim.world)",
    )
    parser.add_argument(
        "--dataset",
        type=int,
        metavar="N",
        help=f"simulation: put the mugs of placement dataset N (1-{len(thesis.DATASETS)}) on the counter "
        "(default 1)",
    )
    parser.add_argument(
        "--once", action="store_true", help="start at once, run one job, print a summary, exit"
    )
    parser.add_argument(
        "--speed",
        type=float,
        metavar="X",
        help="simulation: X simulated seconds per second (default: config)",
    )
    parser.add_argument("--seed", type=int, default=None, metavar="S", help="simulation: detector noise seed")
    parser.add_argument("--record-dir", type=Path, metavar="DIR", help="where the session's MCAP file goes")
    parser.add_argument("--config", type=Path, metavar="FILE", help="TOML file overriding the defaults")
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; default: config)",
    )
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint of a peer to connect to (repeatable; default: config)",
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="allow plain (non-TLS) endpoints other machines can reach: anyone who reaches them can command "
        "the arm (default: refused; see docs/service.md for TLS)",
    )
    parser.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    listen = tuple(_endpoints(args.listen, "--listen")) if args.listen else config.zenoh.listen
    connect = tuple(_endpoints(args.connect, "--connect")) if args.connect else config.zenoh.connect
    if args.dataset is not None and not 1 <= args.dataset <= len(thesis.DATASETS):
        raise UsageError(f"--dataset {args.dataset}: choose a dataset 1-{len(thesis.DATASETS)}")
    speed: float | None = args.speed
    if speed is not None and not 0.1 <= speed <= 1000.0:
        raise UsageError(f"--speed {speed:g}: choose 0.1-1000 simulated seconds per second")
    options = RunOptions(
        listen=listen,
        connect=connect,
        record_dir=args.record_dir or config.recording.dir,
        once=StartRequest() if args.once else None,
        insecure=args.insecure,
    )
    tolerated_exposure(config, options)  # refused before any simulator or device starts
    associate = association()
    with planning_pool(args.log_level) as pool, SdNotifier.from_env() as notifier:
        result = asyncio.run(_serve(args, config, speed, options, associate, pool, notifier))
    if args.once:
        _print_summary(result)
        return 0 if result.end_state == "done" else 1
    return 0


def planning_pool(log_level: str = "info") -> concurrent.futures.ProcessPoolExecutor:
    """One worker process for placement and motion planning (forkserver: never fork Zenoh's threads),
    logging to stderr at the command line's ``--log-level``."""
    return concurrent.futures.ProcessPoolExecutor(
        max_workers=1,
        mp_context=multiprocessing.get_context("forkserver"),
        initializer=_planning_worker,
        initargs=(log_level,),
    )


def _planning_worker(log_level: str) -> None:
    """Planning is background work: below the daemon's priority, so a busy planner cannot delay the loop
    that publishes telemetry and answers commands when the CPUs are short."""
    os.nice(_PLANNING_NICENESS)
    configure_cli_logging(log_level)


async def _serve(
    args: argparse.Namespace,
    config: Config,
    speed: float | None,
    options: RunOptions,
    associate: Associate,
    pool: concurrent.futures.Executor,
    notifier: SdNotifier,
) -> RunResult:
    """Open the backend on the event loop that will drive its devices, then serve."""
    backend = await _backend(args, config, speed, pool)
    return await serve(config, backend, associate, options, notifier=notifier, executor=pool)


async def _backend(
    args: argparse.Namespace, config: Config, speed: float | None, pool: concurrent.futures.Executor
) -> Backend:
    # A cell the arm cannot serve is refused before any device moves (or any simulator starts).
    check_cell_reachable(config, ArmModel.load())
    if args.sim or config.backend == "sim":
        world = args.world or config.sim.world
        seed = config.sim.seed if args.seed is None else args.seed
        backend = await open_sim_backend(
            config, world=world, dataset=args.dataset or 1, speed=speed, seed=seed, executor=pool
        )
    else:
        for flag, value in (("--world", args.world), ("--dataset", args.dataset), ("--seed", args.seed)):
            if value is not None:
                raise UsageError(f"{flag} sets up the simulated cell; add --sim (backend is hardware)")
        if speed is not None:
            raise UsageError("--speed sets up the simulated cell; add --sim (backend is hardware)")
        backend = await open_hardware_backend(config, executor=pool)
    if isinstance(backend.motion, ProcessMotionPlanner):
        backend.motion.warm_up()
    return backend


def association() -> Associate:
    """Lost-mug association (thesis §4.3.1)."""
    return associate


def _endpoints(values: list[str], flag: str) -> list[str]:
    try:
        return [check_endpoint(v, flag) for v in values]
    except ConfigError as e:
        raise UsageError(str(e)) from e


def _print_summary(result: RunResult) -> None:
    s = result.summary
    out = sys.stdout
    out.write(f"job ended in state {result.end_state}\n")
    out.write(f"detected {s.detected}, planned {s.planned}, placed {s.placed}, failed {s.failed}\n")
    out.write(f"grasp failures {s.grasp_failures}, drops {s.drops}, duration {s.duration_s:.1f} s\n")
    out.write(f"recording {result.recording}\n")
