"""The sort methods of §4.2.2 that give the initial packing order (κ)."""

from __future__ import annotations

import random
from enum import StrEnum

from planning.placement.problem import Problem


class Sort(StrEnum):
    CIF = "cif"  # closest item first: nearest the arm base along x, then along y
    NIS_L = "nis-l"  # non-increasing length (brim diameter)
    NIS_W = "nis-w"  # non-increasing width (with handle)
    NDS_L = "nds-l"  # non-decreasing length
    NDS_W = "nds-w"  # non-decreasing width
    RO = "ro"  # random order


def parse_sort(name: str) -> Sort:
    try:
        return Sort(name.lower())
    except ValueError as e:
        raise ValueError(f"unknown sort {name!r} (known: {', '.join(s.value for s in Sort)})") from e


def cif_order(problem: Problem) -> list[int]:
    bx, by = problem.arm_base_mm
    return sorted(
        range(len(problem.mugs)),
        key=lambda i: (abs(problem.mugs[i].x_mm - bx), abs(problem.mugs[i].y_mm - by), i),
    )


def sorted_order(problem: Problem, sort: Sort, rng: random.Random | None = None) -> list[int]:
    """Mug indices in the order ``sort`` gives; size ties keep the closest-item-first order."""
    base = cif_order(problem)
    if sort is Sort.CIF:
        return base
    if sort is Sort.RO:
        order = list(range(len(problem.mugs)))
        (rng or random.Random(0)).shuffle(order)
        return order
    types = problem.mug_types
    if sort in (Sort.NIS_L, Sort.NDS_L):
        size = [types[m.type].diameter_mm for m in problem.mugs]
    else:
        size = [types[m.type].width_mm for m in problem.mugs]
    sign = -1 if sort in (Sort.NIS_L, Sort.NIS_W) else 1
    return sorted(base, key=lambda i: sign * size[i])
