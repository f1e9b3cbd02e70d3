"""The planner's stand-alone dataset defaults must describe the same cell as the embedded config."""

from daemon.config import load_config
from planning.placement import dataset_problem
from planning.placement.datasets import cell_dataset_problem


def test_dataset_defaults_match_the_embedded_cell() -> None:
    cell = load_config().cell
    for n in (1, 2, 3):
        assert dataset_problem(n) == cell_dataset_problem(cell, n)
