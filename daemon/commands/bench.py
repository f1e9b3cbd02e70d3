"""``dishbot bench …``: every benchmark prints a readable table, or with ``--json`` one JSON document."""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Mapping, Sequence

# Each module defines ``register(bench_subparsers)`` adding one benchmark whose parser sets ``handler``.
BENCH_MODULES: tuple[str, ...] = (
    "daemon.commands.bench_daemon",
    "daemon.commands.bench_bus",
    "daemon.commands.bench_placement",
    "daemon.commands.bench_motion",
    "daemon.commands.bench_perception",
    "daemon.commands.bench_sim",
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("bench", help="run a benchmark and print its table (or --json)")
    bench_sub = parser.add_subparsers(dest="bench", metavar="BENCHMARK", required=True)
    for name in BENCH_MODULES:
        importlib.import_module(name).register(bench_sub)


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of the table")


def format_table(columns: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A plain-text table with right-aligned numbers, as the benchmarks print it."""
    cells = [[str(c) for c in columns]] + [[_cell(v) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(columns))]
    lines = []
    for n, row in enumerate(cells):
        lines.append(
            "  ".join(
                v.rjust(w) if n and _numeric(v) else v.ljust(w) for v, w in zip(row, widths, strict=True)
            )
        )
        if n == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(line.rstrip() for line in lines)


def emit(
    title: str,
    columns: Sequence[str],
    rows: Sequence[Sequence[object]],
    *,
    as_json: bool,
    extra: Mapping[str, object] | None = None,
) -> None:
    """Print a benchmark's result: the table (with ``extra`` as key: value lines) or JSON."""
    if as_json:
        doc: dict[str, object] = {
            "benchmark": title,
            "rows": [dict(zip(columns, r, strict=True)) for r in rows],
        }
        doc.update(extra or {})
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return
    print(title)
    print(format_table(columns, rows))
    for key, value in (extra or {}).items():
        print(f"{key}: {_cell(value)}")


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def _numeric(text: str) -> bool:
    try:
        float(text.split(" ")[0])
    except ValueError:
        return False
    return True
