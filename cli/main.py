"""The ``dishbot`` command line. Each verb lives in its own module under ``cli.commands``.

Running a verb imports the module that implements it and no other (``VERBS`` says which); ``--help`` lists
every verb from ``VERBS`` alone. Each module keeps its heavy imports (MuJoCo, scipy, Pinocchio, OpenCV,
OR-Tools, numpy) inside the functions that run the verb: ``--help`` and the client verbs start fast and a
plain install (no ``sim`` extra) can run them (tests/daemon/test_cli_imports.py checks both).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Callable, Collection, Sequence
from typing import Final, NamedTuple, NoReturn

from cli.extras import missing_extra
from cli.logs import LEVELS, configure_cli_logging


class Verb(NamedTuple):
    """A top-level verb: the module whose ``register(subparsers)`` adds it, its line in ``--help``, and
    whether it can log. A verb that cannot (``logs=False``) never imports structlog, so the command line
    leaves it unconfigured and the verb starts without it (tests/daemon/test_cli_imports.py checks that
    such a verb imports no structlog: nothing it runs could log to stdout unconfigured).

    ``quick_exit``: when the verb runs as the process's command (``main()`` without ``argv``), the process
    ends as soon as it returns and its output is flushed, without the interpreter's teardown (collecting
    and freeing every object of the libraries it loaded, their C++ destructors): about a tenth of a
    ``dishbot plan`` (45 ms of CPU). Only for a verb that leaves nothing to finish: no threads, no log
    handlers, its files written whole before it returns."""

    module: str
    help: str
    logs: bool = True
    quick_exit: bool = False


# Every verb in the order ``dishbot --help`` lists them, as its module registers them (the listing is
# checked against the modules' own parsers). Each module defines ``register(subparsers)``, which adds its
# verbs and sets ``handler`` on the parser: a callable taking the parsed namespace and returning the exit
# code. Named, not imported: the benchmarks are the top layer, which nothing imports statically.
VERBS: Final[dict[str, Verb]] = {
    "bench": Verb("bench.cli", "run a benchmark and print its table (or --json)"),
    "config": Verb("cli.commands.config_cmd", "show the effective configuration", logs=False),
    "statechart": Verb(
        "cli.commands.statechart_cmd",
        "print the statechart (states, events, guards) as a Mermaid stateDiagram",
        logs=False,
    ),
    "record": Verb(
        "cli.commands.record", "inspect session recordings (MCAP): summary and outcome, or a picture"
    ),
    "plan": Verb(
        "cli.commands.plan", "plan the mugs' tray positions and placing order", logs=False, quick_exit=True
    ),
    "run": Verb(
        "cli.commands.run",
        "run the daemon (simulated cell with --sim); --once runs one loading job and exits",
    ),
    "replay": Verb(
        "cli.commands.replay",
        "re-run a recorded job through the daemon on simulated time, with injected faults",
    ),
    "status": Verb(
        "cli.commands.client",
        "daemon command: print the daemon's state, job progress and the commands allowed now",
    ),
    "start": Verb(
        "cli.commands.client",
        "daemon command: start a loading job (simulation: --dataset or --mugs set the counter up first)",
    ),
    "pause": Verb(
        "cli.commands.client", "daemon command: stop motion where it is; resume continues from there"
    ),
    "resume": Verb("cli.commands.client", "daemon command: continue a paused job where it stopped"),
    "stop": Verb("cli.commands.client", "daemon command: abandon the job: stop motion, go back to idle"),
    "estop": Verb(
        "cli.commands.client",
        "daemon command: emergency stop: stop the arm, then switch its torque off; only reset leaves",
    ),
    "reset": Verb("cli.commands.client", "daemon command: leave fault or estop for idle"),
    "list": Verb("cli.commands.client", "list the robots alive at the endpoint (their liveliness tokens)"),
    "monitor": Verb("cli.commands.monitor", "show running daemons' live state, joints and gripper force"),
    "security": Verb(
        "cli.commands.security",
        "set up TLS certificates, passwords and roles for commanding a robot from other machines",
    ),
    "router": Verb(
        "cli.commands.router",
        "run a Zenoh router for a fleet, with the same TLS, passwords and roles as the daemon",
    ),
    "servo": Verb("cli.commands.servo", "find Dynamixel servos and change their id or baud rate"),
    "fsr": Verb("cli.commands.fsr", "the force-sensing resistor in the gripper pad"),
    "sim": Verb(
        "cli.commands.sim",
        "simulated devices: the servo chain (bus) or the whole cell as separate devices (rig)",
    ),
    "arm": Verb("cli.commands.arm", "kinematics of the arm: forward, inverse, workspace, calibration"),
    "detect": Verb("cli.commands.detect", "detect the mugs in a depth image"),
    "calibrate": Verb(
        "cli.commands.calibrate", "find the camera's pose from an image of a ChArUco board on the table"
    ),
}
COMMAND_MODULES: Final = tuple(dict.fromkeys(v.module for v in VERBS.values()))
# The options before the verb that take a value (``--log-level debug``).
_VALUED_OPTIONS: Final = ("--log-level", "--profile")

Handler = Callable[[argparse.Namespace], int]


def build_parser(verbs: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The command line's parser. ``verbs`` None: every verb registered by its module (the whole command
    line, for its documentation and tests); otherwise only the modules of ``verbs`` are imported, and every
    other verb is listed by name and help line, so ``--help`` reads the same."""
    parser = argparse.ArgumentParser(
        prog="dishbot",
        description="Load the mugs on a kitchen counter into a dishwasher tray with a low-cost robot arm.",
    )
    parser.add_argument(
        "--log-level",
        choices=LEVELS,
        default="info",
        help="least severe log event written to stderr (default: info); stdout carries only results",
    )
    parser.add_argument(
        "--profile",
        metavar="FILE",
        help="client verbs: the profile to connect with (dishbot security init writes one; also "
        "$DISHBOT_PROFILE)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wanted = None if verbs is None else {VERBS[v].module for v in verbs if v in VERBS}
    for module in COMMAND_MODULES:
        if wanted is None or module in wanted:
            importlib.import_module(module).register(sub)
            continue
        for name, verb in VERBS.items():
            if verb.module == module:
                sub.add_parser(name, help=verb.help)
    return parser


def named_verb(argv: Sequence[str]) -> str | None:
    """The verb ``argv`` runs (its first word that is not an option or an option's value), or None."""
    args = iter(argv)
    for arg in args:
        if arg == "--":
            return next(args, None)
        if arg.startswith("-"):
            # argparse takes an unambiguous prefix of an option too (``--log debug``).
            if "=" not in arg and len(arg) > 2 and any(o.startswith(arg) for o in _VALUED_OPTIONS):
                next(args, None)
            continue
        return arg
    return None


def parse(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """``argv`` (default: the process's) parsed with only what its verb needs imported."""
    args_list = sys.argv[1:] if argv is None else list(argv)
    verb = named_verb(args_list)
    args = build_parser(() if verb is None else (verb,)).parse_args(args_list)
    if not hasattr(args, "handler"):  # the verb was not where ``named_verb`` looked: take every module
        args = build_parser().parse_args(args_list)
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the verb of ``argv`` (None: the process's own command line) and returns its exit code; with
    ``argv`` None a ``quick_exit`` verb ends the process instead (``Verb``)."""
    args = parse(argv)
    # MuJoCo's OpenGL backend, for a verb that imports MuJoCo before ``sim`` (which sets the same default):
    # without a display only offscreen EGL renders here. A MUJOCO_GL of the user's own wins.
    os.environ.setdefault("MUJOCO_GL", "egl")
    code = _run(args)
    if argv is None and VERBS[args.command].quick_exit:
        _exit_now(code)
    return code


def _exit_now(code: int) -> NoReturn:
    """Ends the process with ``code`` once stdout and stderr are flushed (a reader gone from stdout: 141, as
    ``main`` says it)."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        code = 141
    except (OSError, ValueError):
        pass
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()
    os._exit(code)


def _run(args: argparse.Namespace) -> int:
    # Here, not at the top: ``--help`` exits in ``parse`` without the validator these errors build on.
    from daemon.errors import ConfigError, UsageError

    if VERBS[args.command].logs:
        configure_cli_logging(args.log_level)
    handler: Handler = args.handler
    try:
        return handler(args)
    except (UsageError, ConfigError) as e:
        print(f"dishbot {args.command}: error: {e}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:
        message = missing_extra(e)
        if message is None:
            raise
        print(f"dishbot {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader of stdout went away (e.g. `| head`); Python would otherwise complain at exit.
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - replaced for the rest of the process
        return 141


if __name__ == "__main__":
    sys.exit(main())
