"""One change to a decoded JSON document, for the tests of what a parser says about each bad field."""

from __future__ import annotations

import copy
from typing import Any, Final

DELETE: Final = object()  # as ``value``: the key is removed


def edited(doc: dict[str, Any], path: str, value: object) -> dict[str, Any]:
    """A deep copy of ``doc`` with the value at the dotted ``path`` (``mugs.0.x_mm``: digits index lists)
    set to ``value``, or removed when it is ``DELETE``."""
    out = copy.deepcopy(doc)
    *parents, last = path.split(".")
    node: Any = out
    for key in parents:
        node = node[int(key)] if key.isdigit() else node[key]
    index = int(last) if last.isdigit() else last
    if value is DELETE:
        del node[index]
    else:
        node[index] = value
    return out
