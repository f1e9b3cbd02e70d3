"""``dishbot bench …``: every benchmark prints a readable table, or with ``--json`` one JSON document.

Benchmarks are the top layer: they import whatever they measure and nothing imports them; the command
line finds this module by name.
"""

from __future__ import annotations

import argparse
import importlib

# Each module defines ``register(bench_subparsers)`` adding one benchmark whose parser sets ``handler``.
BENCH_MODULES: tuple[str, ...] = (
    "bench.daemon",
    "bench.bus",
    "bench.placement",
    "bench.motion",
    "bench.perception",
    "bench.sim",
    "bench.remote",
    "bench.replay",
    "bench.soak",
    "bench.suite",
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("bench", help="run a benchmark and print its table (or --json)")
    bench_sub = parser.add_subparsers(dest="bench", metavar="BENCHMARK", required=True)
    for name in BENCH_MODULES:
        importlib.import_module(name).register(bench_sub)
