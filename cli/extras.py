"""The optional parts of dishbot: which ``pyproject.toml`` extra installs a library only some verbs need.

A plain install runs the daemon on hardware and every client verb. A verb that reaches for a library it
does not have (``dishbot run --sim`` on the MuJoCo cell, ``bench sim``) fails with one line naming the extra
to install instead of a traceback; ``cli.main`` prints it.
"""

from __future__ import annotations

from typing import Final

# Top-level import name -> (what needs it, the extra that installs it).
EXTRAS: Final[dict[str, tuple[str, str]]] = {
    "mujoco": ("the MuJoCo cell", "sim"),
}


def missing_extra(error: ModuleNotFoundError) -> str | None:
    """What to tell the user when ``error`` is a library an extra installs; None for any other module (a
    broken install or a bug, which keeps its traceback)."""
    known = EXTRAS.get((error.name or "").partition(".")[0])
    if known is None:
        return None
    what, extra = known
    return f"{what} needs the '{extra}' extra: pip install 'dishbot[{extra}]'"
