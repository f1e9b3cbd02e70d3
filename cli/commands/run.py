"""``dishbot run``: the daemon. It waits in idle for ``start``; with ``--once`` it runs one job and exits.

The clock is chosen here: the wall clock for the robot (and for the simulated cell on pseudo-terminals), a
simulated clock for the simulated cell, at ``--speed`` (``max`` for ``--once``)."""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import dataclasses
import multiprocessing
import multiprocessing.forkserver
import os
import sys
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from cli.logs import configure_cli_logging
from cli.progress import Progress
from daemon.config import check_endpoint, load_config
from daemon.errors import ConfigError, UsageError
from description import thesis

if TYPE_CHECKING:
    from daemon.app import RunOptions, RunResult, ServeHooks
    from daemon.backend import Backend
    from daemon.clock import SessionClock
    from daemon.config import Config
    from daemon.job import StartRequest
    from daemon.log_relay import RecordQueue
    from daemon.sdnotify import SdNotifier
    from perception.interfaces import Associate
    from replay.faults import FaultInjector

_PLANNING_NICENESS = 10
DEFAULT_FOXGLOVE = "127.0.0.1:8765"


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
        "--mugs",
        type=Path,
        metavar="FILE",
        help="simulation, with --once: put these mugs on the counter for the job instead of a dataset, "
        'a JSON list [{"id", "type", "x_m", "y_m"}] as `dishbot start --mugs` takes (a daemon waiting for '
        "start gets them from `dishbot start --mugs`)",
    )
    parser.add_argument(
        "--once", action="store_true", help="start at once, run one job, print a summary, exit"
    )
    parser.add_argument(
        "--speed",
        metavar="X",
        help="simulation: X simulated seconds per wall second (0.1-1000), or max: as fast as the machine "
        "allows (default: max with --once, else the config's sim.speed, 1)",
    )
    parser.add_argument(
        "--transport",
        choices=("inprocess", "pty"),
        help="simulation, MuJoCo cell: reach the simulated servos and FSR in-process on simulated time, or "
        "on pseudo-terminals in real time (default: config sim.transport, inprocess)",
    )
    parser.add_argument("--seed", type=int, default=None, metavar="S", help="simulation: detector noise seed")
    parser.add_argument("--record-dir", type=Path, metavar="DIR", help="where the session's MCAP file goes")
    parser.add_argument("--config", type=Path, metavar="FILE", help="TOML file overriding the defaults")
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:3474 (repeatable; default: config)",
    )
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint of a peer or router to connect to, e.g. tcp/127.0.0.1:7447 for a zenohd already "
        "running (repeatable; default: config)",
    )
    parser.add_argument(
        "--foxglove",
        nargs="?",
        const=DEFAULT_FOXGLOVE,
        metavar="HOST:PORT",
        help=f"serve the live Foxglove view over WebSocket (default address {DEFAULT_FOXGLOVE}; "
        "a non-loopback one needs [foxglove] insecure = true; default: config foxglove.listen)",
    )
    parser.add_argument(
        "--faults",
        type=Path,
        metavar="FILE",
        help="simulation: inject the faults a fault file lists ([[fault]] tables; see docs/recording.md)",
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="allow plain (non-TLS) endpoints other machines can reach: anyone who reaches them can command "
        "the arm (default: refused; see docs/service.md for TLS)",
    )
    parser.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from daemon.log_relay import output_guarded

    # From the first log line: a dead output (``| head`` gone) drops lines, it never stops the set-up.
    with output_guarded():
        return _run_guarded(args)


def _run_guarded(args: argparse.Namespace) -> int:
    from daemon.app import RunOptions
    from daemon.sdnotify import SdNotifier

    config = load_config(args.config)
    listen = tuple(_endpoints(args.listen, "--listen")) if args.listen else config.zenoh.listen
    connect = tuple(_endpoints(args.connect, "--connect")) if args.connect else config.zenoh.connect
    if args.dataset is not None and not 1 <= args.dataset <= len(thesis.DATASETS):
        raise UsageError(f"--dataset {args.dataset}: choose a dataset 1-{len(thesis.DATASETS)}")
    clock = session_clock(args, config)
    once = once_request(args, config)
    injector = fault_injector(args, config)
    if args.seed is not None:  # the recording's header shows the seed the simulated cell really used
        config = dataclasses.replace(config, sim=dataclasses.replace(config.sim, seed=args.seed))
    foxglove = _foxglove_address(args.foxglove, config)
    worker_logs: RecordQueue = multiprocessing.get_context("forkserver").Queue(maxsize=10_000)
    options = RunOptions(
        listen=listen,
        connect=connect,
        record_dir=args.record_dir or config.recording.dir,
        once=once,
        foxglove=foxglove,
        worker_logs=worker_logs,
        insecure=args.insecure,
    )
    if injector is not None:
        options = injector.prepare(options)
    from daemon.app import listen_in_use, tolerated_exposure

    tolerated_exposure(config, options)  # refused before any simulator or device starts
    taken = listen_in_use(options.listen)
    if taken is not None:
        raise UsageError(taken)
    associate = association()
    hooks = injector.hooks() if injector is not None else None
    if args.once:  # one finite job: say which mug it is at, on stderr
        hooks = _with_progress(hooks, MugProgress(Progress("dishbot run", 0, unit="mug"), clock.simulated))
    try:
        pool = planning_pool(args.log_level, worker_logs, background=not clock.simulated)
        with pool, SdNotifier.from_env() as notifier:
            result = clock.run(_serve(args, config, clock, options, associate, pool, notifier, hooks))
    finally:
        if injector is not None:
            injector.close()
    if args.once:
        if injector is None:
            _print_summary(result)
        else:
            _print_summary(result, injector.fired, [o.line() for o in injector.unfired()])
        return 0 if result.end_state == "done" else 1
    return 0


def session_clock(args: argparse.Namespace, config: Config) -> SessionClock:
    """The wall clock on the robot and for the cell on pseudo-terminals; otherwise simulated time at
    ``--speed`` (default ``max`` with ``--once``, else ``sim.speed``). Bad flags are usage errors."""
    from daemon.clock import RealClock, SimulatedClock, parse_speed

    speed: float | None = None
    if args.speed is not None:
        try:
            speed = parse_speed(args.speed)
        except ValueError as e:
            raise UsageError(f"--speed {e}") from e
    sim = args.sim or config.backend == "sim"
    if not sim:
        for flag, value in (
            ("--world", args.world),
            ("--dataset", args.dataset),
            ("--mugs", args.mugs),
            ("--seed", args.seed),
            ("--speed", args.speed),
            ("--transport", args.transport),
        ):
            if value is not None:
                raise UsageError(f"{flag} sets up the simulated cell; add --sim (backend is hardware)")
        return RealClock()
    world = args.world or config.sim.world
    transport = args.transport or config.sim.transport
    if world == "kinematic" and args.transport is not None:
        raise UsageError(f"--transport {args.transport}: the kinematic cell has no serial devices")
    if world == "mujoco" and transport == "pty":
        if args.speed is not None and speed != 1.0:
            raise UsageError(
                f"--speed {args.speed}: the MuJoCo cell on pseudo-terminals runs in real time (its device "
                "simulators keep wall-clock time); use --transport inprocess to run faster"
            )
        return RealClock()
    if args.speed is None:
        speed = None if args.once else config.sim.speed
    return SimulatedClock(speed=speed)


def once_request(args: argparse.Namespace, config: Config) -> StartRequest | None:
    """The ``--once`` job's ``start`` (None without ``--once``). With ``--mugs`` it carries the file's mugs,
    checked now as the daemon checks ``start --mugs`` (a bad file is a usage error): the job sets the
    counter up with them as a ``start`` command does, and its recording's header lists them, so it replays.
    Without ``--once`` the mugs are refused: the cell starts with a dataset's counter, the one a recording
    of the waiting daemon's first job names."""
    from daemon.job import StartRequest

    if args.mugs is not None:
        if args.dataset is not None:
            raise UsageError("--dataset and --mugs both set the counter up: give one of them")
        if not args.once:
            raise UsageError(
                "--mugs sets up the counter of the --once job; a daemon waiting for start takes the mugs "
                "from `dishbot start --mugs FILE`"
            )
    if not args.once:
        return None
    from cli.mugs_file import listed_mugs

    return StartRequest(mugs=listed_mugs(args.mugs, config) if args.mugs is not None else None)


def fault_injector(args: argparse.Namespace, config: Config) -> FaultInjector | None:
    """The faults ``--faults`` lists, read and checked before anything starts (a bad file is a usage
    error); they act on the simulated cell only."""
    if args.faults is None:
        return None
    if not (args.sim or config.backend == "sim"):
        raise UsageError("--faults injects faults into the simulated cell; add --sim (backend is hardware)")
    from replay.faults import FaultInjector, load_fault_file

    return FaultInjector(load_fault_file(args.faults, config=config))


def planning_pool(
    log_level: str = "info", log_records: RecordQueue | None = None, *, background: bool = True
) -> concurrent.futures.ProcessPoolExecutor:
    """One worker process for placement and motion planning (forkserver: never fork Zenoh's threads),
    logging to stderr at the command line's ``--log-level`` and, when given, to ``log_records`` (a
    forkserver queue) for the daemon's ``log`` topic. The worker and the forkserver die with this process,
    even by SIGKILL (``daemon.lifeline``). ``background``: the worker runs below the daemon's priority
    (on the wall clock; on a simulated clock the loop waits for every plan, so the planner is the job's
    critical path and runs at the daemon's own priority)."""
    context = multiprocessing.get_context("forkserver")
    if threading.current_thread() is threading.main_thread():
        # Started now, from the thread that lives as long as the process: the forkserver's death signal
        # follows the thread that started it.
        context.set_forkserver_preload(["__main__", "daemon.forkserver_preload"])
        multiprocessing.forkserver.ensure_running()
    return concurrent.futures.ProcessPoolExecutor(
        max_workers=1,
        mp_context=context,
        initializer=_planning_worker,
        initargs=(log_level, log_records, os.getpid(), background),
    )


def _planning_worker(
    log_level: str, log_records: RecordQueue | None, daemon_pid: int, background: bool = True
) -> None:
    """Planning on the wall clock is background work: below the daemon's priority, so a busy planner
    cannot delay the loop that publishes telemetry and answers commands when the CPUs are short. On a
    simulated clock time stands still while a plan is computed (the loop waits for it), so a lower
    priority would only make the job wait longer on a busy machine. It ends with the forkserver it was
    forked from and with the daemon it works for."""
    from daemon.lifeline import die_with_parent, exit_with

    die_with_parent()
    exit_with(daemon_pid)
    if background:
        os.nice(_PLANNING_NICENESS)
    configure_cli_logging(log_level)
    if log_records is not None:
        from daemon.log_relay import forward_to

        forward_to(log_records)


def _foxglove_address(flag: str | None, config: Config) -> tuple[str, int] | None:
    """``--foxglove [HOST:PORT]``, else the config's ``[foxglove] listen`` (None: no live server)."""
    from daemon.config import check_foxglove_listen

    if flag is None:
        return config.foxglove.address
    try:
        return check_foxglove_listen(flag, "--foxglove", insecure=config.foxglove.insecure)
    except ConfigError as e:
        raise UsageError(str(e)) from e


async def _serve(
    args: argparse.Namespace,
    config: Config,
    clock: SessionClock,
    options: RunOptions,
    associate: Associate,
    pool: concurrent.futures.Executor,
    notifier: SdNotifier,
    hooks: ServeHooks | None = None,
) -> RunResult:
    """Open the backend on the event loop that will drive its devices (the clock's), then serve."""
    from daemon.app import serve

    backend = await _backend(args, config, clock, pool)
    return await serve(config, backend, associate, options, notifier=notifier, executor=pool, hooks=hooks)


async def _backend(
    args: argparse.Namespace, config: Config, clock: SessionClock, pool: concurrent.futures.Executor
) -> Backend:
    import structlog

    from daemon.backend import SimOptions
    from daemon.cell import open_backend
    from daemon.clock import SimulatedClock, describe_speed
    from daemon.planners import ProcessMotionPlanner

    sim: SimOptions | None = None
    if args.sim or config.backend == "sim":
        sim = SimOptions(
            world=args.world, dataset=args.dataset or 1, transport=args.transport, seed=args.seed
        )
    backend = await open_backend(config, sim=sim, clock=clock, executor=pool)
    if sim is not None and isinstance(clock, SimulatedClock):
        structlog.get_logger("daemon.run").info(
            "simulated_time", speed=describe_speed(clock.speed), world=args.world or config.sim.world
        )
    if args.once and isinstance(backend.motion, ProcessMotionPlanner):
        # One job to run (and to time): the planner is built before it starts, not during its first plan;
        # waited for in a thread, as executor work, so that simulated time stands still meanwhile.
        await asyncio.to_thread(backend.motion.warm_up().result)
    return backend


def association() -> Associate:
    """Lost-mug association (thesis §4.3.1)."""
    from perception import associate

    return associate


def _endpoints(values: list[str], flag: str) -> list[str]:
    try:
        return [check_endpoint(v, flag) for v in values]
    except ConfigError as e:
        raise UsageError(str(e)) from e


def _print_summary(
    result: RunResult, fired: Sequence[Mapping[str, object]] = (), unfired: Sequence[str] = ()
) -> None:
    s = result.summary
    out = sys.stdout
    out.write(f"job ended in state {result.end_state}\n")
    out.write(f"detected {s.detected}, planned {s.planned}, placed {s.placed}, failed {s.failed}\n")
    if s.left_out:
        out.write(f"left out of the plan {len(s.left_out)}:\n")
        for line in s.left_out:
            out.write(f"  {line}\n")
    out.write(f"grasp failures {s.grasp_failures}, drops {s.drops}, duration {s.duration_s:.1f} s\n")
    if s.recording_dropped:
        out.write(f"recording lost {s.recording_dropped} messages (the disk failed or was too slow)\n")
    if result.log_lines_lost:
        out.write(
            f"log output lost {result.log_lines_lost} lines (stderr was closed; the recording has them)\n"
        )
    if result.simulated:
        out.write(f"{time_ratio_line(s.duration_s, result.wall_s)}\n")
    for line in result.outcome.failed_lines():
        out.write(f"failed {line}\n")
    for reason in result.outcome.faults:
        out.write(f"fault: {reason}\n")
    for record in fired:
        out.write(f"{fault_fired_line(record)}\n")
    for line in unfired:  # a fault of the file that did not happen: the run did not test what it says
        out.write(f"{line}\n")
    out.write(f"recording {result.recording}\n")


def fault_fired_line(record: Mapping[str, object]) -> str:
    """``fault fired: servo_overload servo 3 at 12.4 s`` (an injected fault, as ``FaultInjector.fired``
    lists it)."""
    target = ""
    for key in ("servo", "device", "mug"):
        if record.get(key) is not None:
            target += f" {key} {record[key]}"
    at = record.get("fired_at_s")
    when = f"{at:.1f}" if isinstance(at, float | int) else "?"
    line = f"fault fired: {record.get('kind')}{target} at {when} s"
    if isinstance(record.get("ended_at_s"), float | int):
        line += f", ended at {record['ended_at_s']:.1f} s"
    return line


class MugProgress:
    """Follows a ``--once`` job's ``state`` messages: a progress line as each mug begins (``mug k of N``,
    the mugs with a tray slot, else the mugs known), one when the job ends."""

    _ENDS = ("done", "fault", "estop")

    def __init__(self, progress: Progress, simulated: bool) -> None:
        self.progress = progress
        self._simulated = simulated
        self._t0: float | None = None
        self._mug: object = None
        self._ended = False

    def __call__(self, topic: str, payload: Mapping[str, object]) -> None:
        if topic != "state" or self._ended:
            return
        from wire.messages import UNSET, BadMessage, State, convert

        try:
            message = convert(payload, State, name=topic)
        except BadMessage:
            return
        t = message.t
        self._t0 = t if self._t0 is None else self._t0
        simulated_s = t - self._t0 if self._simulated else None
        planned = message.mugs_planned if message.mugs_planned is not UNSET else 0
        failed = message.mugs_failed if message.mugs_failed is not UNSET else 0
        total, placed = message.mugs_total, message.mugs_placed
        finished = placed + failed
        state = message.state.split(".", 1)[0]
        mug = message.current_mug if message.current_mug is not UNSET else None
        if mug is not None and mug != self._mug:
            self.progress.total = max(planned or total, finished + 1)
            self.progress.step(finished + 1, mug, simulated_s=simulated_s)
        self._mug = mug
        if state in self._ENDS and self._t0 is not None:
            self._ended = True
            self.progress.done(f"{state}: {placed} of {planned or total} placed", simulated_s=simulated_s)


def _with_progress(hooks: ServeHooks | None, tap: MugProgress) -> ServeHooks:
    from daemon.app import ServeHooks

    if hooks is None:
        return ServeHooks(on_publish=(tap,))
    return dataclasses.replace(hooks, on_publish=(*hooks.on_publish, tap))


def time_ratio_line(simulated_s: float, wall_s: float) -> str:
    """``simulated 240.9 s in 31.2 s wall (7.7x real time)``."""
    ratio = f"{simulated_s / wall_s:.1f}x" if wall_s > 0 else "-"
    return f"simulated {simulated_s:.1f} s in {wall_s:.1f} s wall ({ratio} real time)"
