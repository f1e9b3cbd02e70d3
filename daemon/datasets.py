"""The thesis datasets set up on the configured cell: one place that decides where their mugs stand."""

from __future__ import annotations

from daemon.config import CellConfig
from description import thesis
from planning.placement import Problem, dataset_problem


def cell_dataset_problem(cell: CellConfig, n: int) -> Problem:
    """Dataset ``n`` with its mugs on the configured counter region. The robot-tray datasets (1-3) use the
    configured tray pose; the full-size-tray ones keep the planner's default tray origin."""
    robot_tray = thesis.DATASETS[n].tray_mm == thesis.ROBOT_TRAY_MM if n in thesis.DATASETS else True
    return dataset_problem(
        n,
        counter_region_m=cell.counter_region_m,
        tray_origin_m=cell.tray_origin_m if robot_tray else None,
    )
