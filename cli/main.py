"""The ``dishbot`` command line. Each verb lives in its own module under ``cli.commands``.

Building the parser imports every verb module, so each keeps its heavy imports (MuJoCo, scipy, Pinocchio,
OpenCV, OR-Tools, numpy) inside the functions that run the verb: ``--help`` and the client verbs start fast
and a plain install (no ``sim`` extra) can run them (tests/daemon/test_cli_imports.py checks).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence

from cli.extras import missing_extra
from cli.logs import LEVELS, configure_cli_logging
from daemon.errors import ConfigError, UsageError

# Each module defines ``register(subparsers)``, which adds its verbs and sets ``handler`` on the parser:
# a callable taking the parsed namespace and returning the exit code. Named, not imported: the benchmarks
# are the top layer, which nothing imports statically.
COMMAND_MODULES: tuple[str, ...] = (
    "bench.cli",
    "cli.commands.config_cmd",
    "cli.commands.statechart_cmd",
    "cli.commands.record",
    "cli.commands.plan",
    "cli.commands.run",
    "cli.commands.replay",
    "cli.commands.client",
    "cli.commands.monitor",
    "cli.commands.security",
    "cli.commands.router",
    "cli.commands.servo",
    "cli.commands.fsr",
    "cli.commands.sim",
    "cli.commands.arm",
    "cli.commands.detect",
    "cli.commands.calibrate",
)

Handler = Callable[[argparse.Namespace], int]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dishbot",
        description="Load the mugs on a kitchen counter into a dishwasher tray with a low-cost robot arm.",
    )
    parser.add_argument(
        "--log-level",
        choices=tuple(LEVELS),
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
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
