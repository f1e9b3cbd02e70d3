"""How verbs print results: a plain-text table for people, or one JSON document with ``--json``."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence


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
