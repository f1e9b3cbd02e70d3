"""Datasets 1-6: the thesis's counts and trays, counter positions inside the region, apart, off the tray."""

from __future__ import annotations

import itertools

import pytest

from description import thesis
from planning.placement import InvalidProblem, Problem, dataset_problem
from planning.placement.datasets import GAP_MM


def counter_footprints(p: Problem) -> list[tuple[float, float, float, float]]:
    """(x0, y0, x1, y1) in world mm: brim plus handle along +x, no tolerance."""
    out = []
    for m in p.mugs:
        t = p.mug_types[m.type]
        r = t.diameter_mm / 2
        out.append((m.x_mm - r, m.y_mm - r, m.x_mm - r + t.width_mm, m.y_mm + r))
    return out


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_dataset_has_the_thesis_counts_and_tray(n: int) -> None:
    p = dataset_problem(n)
    ds = thesis.DATASETS[n]
    assert sum(m.type == "big" for m in p.mugs) == ds.big
    assert sum(m.type == "small" for m in p.mugs) == ds.small
    assert p.tray_size_mm == ds.tray_mm
    assert p == dataset_problem(n)  # deterministic


@pytest.mark.parametrize(
    ("n", "region_mm"),
    [
        (1, (-450, 370, 450, 575)),
        (2, (-450, 370, 450, 575)),
        (3, (-450, 370, 450, 575)),
        (4, (-730, 370, 450, 797)),
        (5, (-730, 370, 450, 797)),
        (6, (-730, 370, 450, 797)),
    ],
)
def test_counter_mugs_stand_apart_inside_the_region_and_off_the_tray(
    n: int, region_mm: tuple[int, int, int, int]
) -> None:
    p = dataset_problem(n)
    boxes = counter_footprints(p)
    x_min, y_min, x_max, y_max = region_mm
    for x0, y0, x1, y1 in boxes:
        assert x_min - 1e-6 <= x0
        assert x1 <= x_max + 1e-6
        assert y_min - 1e-6 <= y0
        assert y1 <= y_max + 1e-6
    for a, b in itertools.combinations(boxes, 2):
        gap = max(b[0] - a[2], a[0] - b[2], b[1] - a[3], a[1] - b[3])
        assert gap >= GAP_MM - 0.2  # positions are rounded to 0.1 mm
    tx0, ty0 = p.tray_origin_mm
    tx1, ty1 = tx0 + p.tray_size_mm[0], ty0 + p.tray_size_mm[1]
    for x0, y0, x1, y1 in boxes:
        assert x1 <= tx0 or x0 >= tx1 or y1 <= ty0 or y0 >= ty1


def test_robot_tray_follows_the_given_origin() -> None:
    p = dataset_problem(2, tray_origin_m=(0.2, -0.1))
    assert p.tray_origin_mm == (200.0, -100.0)


def test_unknown_dataset_is_refused() -> None:
    with pytest.raises(InvalidProblem) as e:
        dataset_problem(7)
    assert str(e.value) == "dataset: unknown dataset 7 (known: 1-6)"
