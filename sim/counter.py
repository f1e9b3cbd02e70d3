"""The counter set-up of a simulated cell: which mugs stand where when a job starts, and the tray they go to.

A dataset's mugs stand where ``planning.placement.cell_dataset_problem`` puts them on the cell's counter
region, so the placement problem the job plans and the simulated counter agree mug for mug. A ``start``
command may list the mugs instead. Both simulated worlds (kinematic and MuJoCo) and the benches set their
counters up here.

Every mug stands upright with its handle pointing away from the arm's shoulder axis
(``planning.arm.grasp.handle_facing_away_rad``): the side grasp comes from behind the mug, and a mug taken
that way ends on the tray with its handle within the slot's bearing (under 20 degrees) of +x, inside the
footprint the placement plans with. The arm has no wrist yaw: side grasp, flip and regrasp mirror the
handle's angle to the approach, so it lands at slot bearing + pick bearing - counter yaw.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from description import thesis
from description.cell import CellLayout, SceneMug, Tray
from description.thesis import MugSpec
from planning.arm.grasp import handle_facing_away_rad
from planning.placement import cell_dataset_problem

# A mug set out on the counter: (id, type name, x_m, y_m) of its axis in the world frame.
CounterEntry = tuple[str, str, float, float]


@dataclass(frozen=True, slots=True)
class Counter:
    """A simulated counter at the start of a job: its mugs, the tray they go to and the dataset they come
    from (None for mugs a ``start`` command listed)."""

    mugs: tuple[SceneMug, ...]
    tray: Tray
    dataset: int | None = None


def dataset_counter(n: int, cell: CellLayout, catalogue: Mapping[str, MugSpec]) -> Counter:
    """Dataset ``n``'s mugs on the cell's counter. The tray is the cell's when the dataset is planned on a
    tray of its size (datasets 1-3 on the robot tray), else the dataset's own tray where
    ``cell_dataset_problem`` puts it (the full-size tray of datasets 4-6)."""
    problem = cell_dataset_problem(cell, n)
    if problem.tray_size_mm == cell.tray.size_mm:
        tray = cell.tray
    else:
        origin = (problem.tray_origin_mm[0] / 1000.0, problem.tray_origin_mm[1] / 1000.0)
        tray = Tray(origin, problem.tray_size_mm)
    entries = [(m.id, m.type, m.x_mm / 1000.0, m.y_mm / 1000.0) for m in problem.mugs]
    return Counter(tuple(counter_mugs(entries, catalogue)), tray, dataset=n)


def listed_counter(
    entries: Sequence[CounterEntry], cell: CellLayout, catalogue: Mapping[str, MugSpec]
) -> Counter:
    """The listed mugs on the counter, to go to the cell's tray."""
    return Counter(tuple(counter_mugs(entries, catalogue)), cell.tray)


def counter_mugs(entries: Sequence[CounterEntry], catalogue: Mapping[str, MugSpec]) -> list[SceneMug]:
    """Counter mugs from (id, type, x, y) entries, upright, each with its handle pointing away from the arm;
    ValueError when a type is not in the catalogue."""
    unknown = sorted({kind for _, kind, _, _ in entries} - set(catalogue))
    if unknown:
        raise ValueError(
            f"mug types {', '.join(unknown)} are not in the catalogue ({', '.join(sorted(catalogue))})"
        )
    return [
        SceneMug(mug_id, catalogue[kind], x, y, yaw_rad=handle_facing_away_rad(x, y))
        for mug_id, kind, x, y in entries
    ]


def require_cell_tray(counter: Counter, cell: CellLayout) -> None:
    """Refuse a counter whose tray is not the cell's, for a world with its tray built into the scene (the
    MuJoCo cell): ValueError with the one message ``dishbot run`` and the benches give."""
    if counter.tray == cell.tray:
        return
    fits = [str(d.number) for d in thesis.DATASETS.values() if d.tray_mm == cell.tray.size_mm]
    use = f"use dataset {', '.join(fits)} or " if fits else "use "
    w, h = counter.tray.size_mm
    cw, ch = cell.tray.size_mm
    raise ValueError(
        f"dataset {counter.dataset} needs the {_tray_name(counter.tray.size_mm)} ({w} x {h} mm), which the "
        f"MuJoCo cell does not have (its tray is the configured {cw} x {ch} mm one); {use}the kinematic cell"
    )


def _tray_name(size_mm: tuple[int, int]) -> str:
    if size_mm == thesis.FULL_TRAY_MM:
        return "full-size tray"
    if size_mm == thesis.ROBOT_TRAY_MM:
        return "robot tray"
    return "tray"
