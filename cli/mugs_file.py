"""A ``--mugs FILE``: the JSON list of counter mugs (``[{"id", "type", "x_m", "y_m"}]``) a simulated counter
is set up with, read the same way by ``dishbot start``, ``dishbot run --once`` and ``dishbot sim rig``, so a
file gets the same one-line error from each.

``start`` sends the list as read (the daemon it talks to checks it against its own config); ``run`` and
``sim rig`` check it here, with the daemon's own ``start`` validator, before anything starts."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.errors import UsageError

if TYPE_CHECKING:
    from daemon.backend import SetupMug
    from daemon.config import Config


def read_mugs_file(path: str | Path) -> object:
    """The file's JSON document, unchecked; ``UsageError`` naming the file when it cannot be read or is not
    JSON."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise UsageError(f"--mugs {path}: cannot read it: {e.strerror}") from e
    except UnicodeDecodeError as e:
        raise UsageError(f"--mugs {path}: not valid JSON: not UTF-8 text at byte {e.start}") from e
    except json.JSONDecodeError as e:
        raise UsageError(f"--mugs {path}: not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from e


def listed_mugs(path: str | Path, config: Config) -> tuple[SetupMug, ...]:
    """The file's mugs, checked as the daemon checks a ``start`` command's ``mugs`` on ``config`` (known
    fields, 1-64 mugs, ids, configured types, coordinates); ``UsageError`` naming the file and the field."""
    from daemon.commands_handler import BadCommand, parse

    listed = read_mugs_file(path)
    try:
        request = parse("start", json.dumps({"mugs": listed}).encode(), config)
    except BadCommand as e:
        raise UsageError(f"--mugs {path}: {e}") from e
    if request is None or request.mugs is None:
        raise UsageError(f"--mugs {path}: lists no mugs")
    return request.mugs
