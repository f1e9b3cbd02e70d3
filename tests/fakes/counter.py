"""A short counter for a simulated job: the first few mugs of dataset 1, where the dataset stands them, as a
``start`` body and a ``--mugs`` file list them and as an in-process ``StartRequest(mugs=...)`` takes them. A
test that shows what a few mugs show runs that job instead of the whole dataset."""

from __future__ import annotations

import json
from pathlib import Path

from daemon.backend import SetupMug
from daemon.config import load_config
from planning.placement import cell_dataset_problem


def setup_mugs(count: int) -> tuple[SetupMug, ...]:
    """The first ``count`` mugs of dataset 1 on the default cell's counter, for ``StartRequest(mugs=...)``."""
    problem = cell_dataset_problem(load_config().cell, 1)
    return tuple(SetupMug(m.id, m.type, m.x_mm / 1000.0, m.y_mm / 1000.0) for m in problem.mugs[:count])


def dataset_mugs(count: int) -> list[dict[str, object]]:
    """``setup_mugs(count)`` as ``{"id", "type", "x_m", "y_m"}`` entries (a ``start`` body's, a ``--mugs``
    file's)."""
    return [{"id": m.mug_id, "type": m.type, "x_m": m.x_m, "y_m": m.y_m} for m in setup_mugs(count)]


def mugs_file(directory: Path, count: int) -> Path:
    """A ``--mugs`` file in ``directory`` listing ``dataset_mugs(count)``."""
    path = directory / f"mugs-{count}.json"
    path.write_text(json.dumps(dataset_mugs(count)), encoding="utf-8")
    return path
