"""What placement planning keeps between runs (``PlanOptions.cache_dir``; ``dishbot plan`` keeps it).

Two pieces of work are pure functions of a few inputs and the same for many problems, so they are kept:

- ``exact.solve``'s proven outcomes (the rectangle optimum, also the mug packer's start). The model reads the
  tray, the footprints of the mug types, how many mugs of each type, the mugs already on the tray, rotation,
  the seed and the deterministic limit (the solver stops on deterministic time, never on the wall clock, on
  one seeded thread), for one build of the model's code and of OR-Tools. Counter positions are not part of
  the model (which counter mug goes where is worked out after it), so every plan of a dataset and every job
  with the same mix of mugs asks the same question. A kept answer spares loading OR-Tools (about 60 ms of
  CPU) and the solve. Only outcomes whose count the solver proved are kept.
- ``mugpack``'s scan orders of a mug type's grid of corners on a tray (48 orders of 16,000-43,000 corners,
  about 20 ms of CPU per type to sort), a function of the tray, the type's size, the arm base and the code.

Each is kept under a digest of everything it depends on, the code that makes it (the source files) and the
library build that computes it (OR-Tools' or numpy's version), written whole or not at all (a temporary file
renamed). A file that cannot be read, parsed or written is passed over: the work is done as if nothing had
been kept, and the plan is the same either way.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path

# Bump when what a kept file means changes without the code's digest changing.
_FORMAT = 1


def default_dir() -> Path | None:
    """``$DISHBOT_CACHE_DIR`` (empty: keep nothing), else ``$XDG_CACHE_HOME/dishbot``, else
    ``~/.cache/dishbot``; placement keeps its files in its ``placement`` folder."""
    given = os.environ.get("DISHBOT_CACHE_DIR")
    if given is not None:
        return Path(given) / "placement" if given else None
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "dishbot" / "placement"


def key(question: object, code: Sequence[str], build: object) -> str | None:
    """The digest of ``question`` (JSON-able), the source files ``code`` (names in this package) and the
    library ``build``; None when the code cannot be read (then nothing is kept)."""
    here = Path(__file__).parent
    h = hashlib.sha256()
    try:
        for name in (*code, "cache.py"):
            h.update((here / name).read_bytes())
    except OSError:
        return None
    text = json.dumps(
        {"format": _FORMAT, "code": h.hexdigest(), "build": build, "question": question}, sort_keys=True
    )
    return hashlib.sha256(text.encode()).hexdigest()


def load_json(directory: Path, digest: str) -> dict[str, object] | None:
    """The answer kept under ``digest``, if there is one that reads back."""
    try:
        doc = json.loads((directory / f"exact-{digest}.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("key") == digest else None


def store_json(directory: Path, digest: str, answer: dict[str, object]) -> None:
    """Keeps ``answer`` under ``digest``."""
    text = json.dumps({**answer, "key": digest})
    _store(directory, f"exact-{digest}.json", lambda path: path.write_text(text, encoding="utf-8"))


def orders_path(directory: Path, digest: str) -> Path:
    """Where the scan orders kept under ``digest`` are (a ``.npy`` file: ``mugpack`` reads and writes it)."""
    return directory / f"scans-{digest}.npy"


def store_file(directory: Path, name: str, write: Callable[[Path], object]) -> None:
    """Keeps the file ``write`` writes (to the path it is given) as ``name`` in ``directory``."""
    _store(directory, name, write)


def _store(directory: Path, name: str, write: Callable[[Path], object]) -> None:
    import tempfile  # only a run that did the work writes

    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".", suffix=Path(name).suffix)
        os.close(fd)
        try:
            write(Path(tmp))
            os.replace(tmp, directory / name)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError:
        pass


def ortools_build() -> list[object] | None:
    """OR-Tools' version and its CP-SAT library's size and time, found without importing it; None when it
    cannot be found (then nothing is kept)."""
    try:
        spec = importlib.util.find_spec("ortools")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    package = Path(next(iter(spec.submodule_search_locations)))
    try:
        versions = sorted(
            e.name for e in os.scandir(package.parent) if e.name.startswith("ortools-") and e.is_dir()
        )
        helpers = sorted((package / "sat" / "python").glob("cp_model_helper*"))
        stats = [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in helpers]
    except OSError:
        return None
    if not versions or not stats:
        return None
    return [versions, stats]
