"""The six placement datasets of §5.3 with deterministic counter-top positions.

Mugs stand on a grid with their whole footprints (brim plus handle along +x, no tolerance) inside the
counter region, at least ``GAP_MM`` apart, so none reaches into the tray next to the region. The grid uses as
many columns and rows as fit, spread evenly over the region. When the mugs cannot fit (the 30-mug datasets),
the region grows away from the tray: its corner nearest the tray (x_max, y_min) stays, x_min moves back and
y_max moves out by one grid pitch at a time, alternately (x first), until the grid holds every mug.
Which mug is big or small is a fixed shuffle seeded by the dataset number. ``cell_dataset_problem`` is the
problem on a configured cell; the simulated counters (``sim.counter``) set the same mugs out.
"""

from __future__ import annotations

import math
import random

from description import thesis
from description.cell import CellLayout
from planning.placement.errors import InvalidProblem
from planning.placement.problem import CounterMug, Problem, default_mug_types

GAP_MM = 20
DEFAULT_COUNTER_REGION_M = (-0.45, 0.37, 0.45, 0.575)
# The tray's corner nearest the arm base (world frame): the robot tray as in default_config.toml [cell],
# the full-size tray centred on the arm's x axis.
ROBOT_TRAY_ORIGIN_M = (0.34, -0.187)
FULL_TRAY_ORIGIN_M = (0.25, -0.26)


def dataset_problem(
    n: int,
    *,
    counter_region_m: tuple[float, float, float, float] = DEFAULT_COUNTER_REGION_M,
    tray_origin_m: tuple[float, float] | None = None,
) -> Problem:
    """Dataset ``n`` (1-6) of §5.3 as a problem: counts and tray from ``description.thesis``."""
    if n not in thesis.DATASETS:
        raise InvalidProblem(f"dataset: unknown dataset {n} (known: 1-{len(thesis.DATASETS)})")
    ds = thesis.DATASETS[n]
    x0, y0, x1, y1 = counter_region_m
    if not (x1 > x0 and y1 > y0):
        raise InvalidProblem(
            f"counter_region_m: expected [x_min, y_min, x_max, y_max], got {counter_region_m}"
        )
    types = default_mug_types()
    kinds = ["big"] * ds.big + ["small"] * ds.small
    random.Random(n).shuffle(kinds)
    big = types["big"]
    pitch_x = (big.width_mm + GAP_MM) / 1000.0
    pitch_y = (big.diameter_mm + GAP_MM) / 1000.0
    count = len(kinds)
    # Brim centres keep the footprint inside the region: r behind and w - r ahead along x, r either side in y.
    r = big.diameter_mm / 2000.0
    ahead = big.width_mm / 1000.0 - r
    grow_x = True
    while True:
        cols = math.floor((x1 - x0 - r - ahead) / pitch_x + 1e-9) + 1
        rows = math.floor((y1 - y0 - 2 * r) / pitch_y + 1e-9) + 1
        if cols * rows >= count:
            break
        if grow_x:
            x0 -= pitch_x
        else:
            y1 += pitch_y
        grow_x = not grow_x
    rows = math.ceil(count / cols)
    step_x = (x1 - x0 - r - ahead) / (cols - 1) if cols > 1 else 0.0
    step_y = (y1 - y0 - 2 * r) / (rows - 1) if rows > 1 else 0.0
    mugs = []
    for k, kind in enumerate(kinds):
        row, col = divmod(k, cols)
        # Row 0 is the one nearest the tray (small y); within a row, nearest the arm (large x) first.
        x_mm = round((x1 - ahead - col * step_x) * 1000.0, 1)
        y_mm = round((y0 + r + row * step_y) * 1000.0, 1)
        mugs.append(CounterMug(f"m{k + 1}", kind, x_mm, y_mm))
    ox, oy = tray_origin_m or (
        ROBOT_TRAY_ORIGIN_M if ds.tray_mm == thesis.ROBOT_TRAY_MM else FULL_TRAY_ORIGIN_M
    )
    return Problem(
        tray_size_mm=ds.tray_mm,
        tray_origin_mm=(round(ox * 1000.0, 1), round(oy * 1000.0, 1)),
        mugs=tuple(mugs),
        mug_types=types,
    )


def cell_dataset_problem(cell: CellLayout, n: int) -> Problem:
    """Dataset ``n`` with its mugs on the cell's counter region. The robot-tray datasets (1-3) use the cell's
    tray pose; the full-size-tray ones keep the full-size tray's default pose (``FULL_TRAY_ORIGIN_M``)."""
    robot_tray = thesis.DATASETS[n].tray_mm == thesis.ROBOT_TRAY_MM if n in thesis.DATASETS else True
    return dataset_problem(
        n,
        counter_region_m=cell.counter_region_m,
        tray_origin_m=cell.tray.origin_m if robot_tray else None,
    )
