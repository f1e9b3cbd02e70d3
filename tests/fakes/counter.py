"""A short counter for a simulated job: the first few mugs of dataset 1, where the dataset stands them, as a
``start`` body and a ``--mugs`` file list them. A test that shows what one or two mugs show runs that job
instead of the whole dataset."""

from __future__ import annotations

import json
from pathlib import Path

from daemon.config import load_config
from planning.placement import cell_dataset_problem


def dataset_mugs(count: int) -> list[dict[str, object]]:
    """The first ``count`` mugs of dataset 1 on the default cell's counter, as ``{"id", "type", "x_m",
    "y_m"}`` entries."""
    problem = cell_dataset_problem(load_config().cell, 1)
    return [
        {"id": m.id, "type": m.type, "x_m": m.x_mm / 1000.0, "y_m": m.y_mm / 1000.0}
        for m in problem.mugs[:count]
    ]


def mugs_file(directory: Path, count: int) -> Path:
    """A ``--mugs`` file in ``directory`` listing ``dataset_mugs(count)``."""
    path = directory / f"mugs-{count}.json"
    path.write_text(json.dumps(dataset_mugs(count)), encoding="utf-8")
    return path
