"""The one TOML writer: the files dishbot writes for people to read and edit again (``dishbot config show``,
the rig's config, fault files), from plain data, so that ``tomllib.loads(dumps(data)) == data``.

Tables become ``[a.b]`` sections after the keys of their parent, lists of tables ``[[a]]`` blocks, and
strings basic TOML strings with every control character escaped (a value can never break a line).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from typing import Any, Final

_BARE_KEY: Final = re.compile(r"^[A-Za-z0-9_-]+\Z")
_ESCAPES: Final = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def dumps(data: Mapping[str, Any]) -> str:
    """A TOML document for ``data``: strings, booleans, integers, floats, lists of them, tables and lists of
    tables (``TypeError`` for anything else)."""
    lines: list[str] = []
    _table(data, [], lines, header=False)
    return "\n".join(lines).strip() + "\n"


def value(item: Any) -> str:
    """One TOML value."""
    if isinstance(item, bool):
        return "true" if item else "false"
    if isinstance(item, int):
        return str(item)
    if isinstance(item, float):
        if math.isnan(item):
            return "nan"
        if math.isinf(item):
            return "inf" if item > 0 else "-inf"
        return repr(item)
    if isinstance(item, str):
        return '"' + "".join(_escaped(c) for c in item) + '"'
    if isinstance(item, Sequence):
        return "[" + ", ".join(value(v) for v in item) + "]"
    raise TypeError(f"cannot write {type(item).__name__} as TOML")


def key(name: str) -> str:
    """A key, bare when TOML allows it, quoted otherwise."""
    return name if _BARE_KEY.fullmatch(name) else value(name)


def _escaped(c: str) -> str:
    if c in _ESCAPES:
        return _ESCAPES[c]
    if ord(c) < 0x20 or ord(c) == 0x7F:
        return f"\\u{ord(c):04x}"
    return c


def _is_tables(item: Any) -> bool:
    return (
        isinstance(item, Sequence)
        and not isinstance(item, str)
        and bool(item)
        and all(isinstance(v, Mapping) for v in item)
    )


def _table(
    data: Mapping[str, Any], path: list[str], lines: list[str], *, header: bool, array: bool = False
) -> None:
    scalars = {k: v for k, v in data.items() if not isinstance(v, Mapping) and not _is_tables(v)}
    if array:
        lines += ["", f"[[{'.'.join(key(p) for p in path)}]]"]
    elif header and (scalars or not data):  # an empty table is still written
        lines += ["", f"[{'.'.join(key(p) for p in path)}]"]
    for name, item in scalars.items():
        lines.append(f"{key(name)} = {value(item)}")
    for name, item in data.items():
        if isinstance(item, Mapping):
            _table(item, [*path, name], lines, header=True)
        elif _is_tables(item):
            for entry in item:
                _table(entry, [*path, name], lines, header=True, array=True)
