"""``mugrefine``: one mug more at a smaller clearance, and the continuous search that widens a layout's gaps.

The clearances it reports are measured again with shapely, independently of the numpy distances it uses."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import box

from planning.placement import PlanOptions, Problem, TrayMug, dataset_problem
from planning.placement.mugpack import fixed_bodies
from planning.placement.mugrefine import clearance_of, one_more, refine
from planning.placement.shapes import Bodies, MugOutline
from tests.planning.placement.test_mug_footprint import outline_parts


def shapely_clearance(
    problem: Problem, mugs: list[tuple[str, float]], brims: list[tuple[float, float]]
) -> float:
    """The least gap between two outlines and twice the least gap to a wall, measured with shapely."""
    tx, ty = problem.tray_size_mm
    walls = box(0, 0, tx, ty).exterior
    parts = [
        outline_parts(problem, t, b, problem.handle_yaw_on_tray(b[0], b[1], rel))
        for (t, rel), b in zip(mugs, brims, strict=True)
    ]
    least = math.inf
    for point, r, bar, th in parts:
        assert box(0, 0, tx, ty).contains(point)
        least = min(least, 2 * (walls.distance(point) - r), 2 * (walls.distance(bar) - th))
    for (p1, r1, b1, t1), (p2, r2, b2, t2) in itertools.combinations(parts, 2):
        least = min(
            least,
            p1.distance(p2) - r1 - r2,
            p1.distance(b2) - r1 - t2,
            b1.distance(p2) - t1 - r2,
            b1.distance(b2) - t1 - t2,
        )
    return least


def test_dataset_1_packs_twelve_at_8_mm_and_the_search_widens_them_to_what_shapely_measures() -> None:
    problem = replace(dataset_problem(1), footprint_kind="mug")
    found = one_more(problem, 11, options=PlanOptions())
    assert found is not None
    assert (found.count, found.packed_at) == (12, 8)
    brims = list(found.refined.brims)
    assert found.refined.clearance == pytest.approx(
        shapely_clearance(problem, list(found.mugs), brims), abs=1e-6
    )
    # measured: 9.54 mm, short of the 10 mm the problem asks (docs/placement.md)
    assert found.refined.clearance >= 9.5
    assert found.refined.iterations > 0


def test_nothing_more_to_place_is_no_search() -> None:
    problem = replace(dataset_problem(3), footprint_kind="mug")
    assert one_more(problem, len(problem.mugs), options=PlanOptions()) is None


brim_layouts = st.lists(
    st.tuples(
        st.sampled_from(["big", "small"]), st.floats(50, 280), st.floats(50, 320), st.floats(-0.5, 0.5)
    ),
    min_size=2,
    max_size=4,
)


@settings(max_examples=15, deadline=None)
@given(brim_layouts)
def test_refining_never_loses_clearance_and_reports_what_shapely_measures(
    layout: list[tuple[str, float, float, float]],
) -> None:
    problem = replace(dataset_problem(1), footprint_kind="mug")
    mugs = [(t, rel) for t, _, _, rel in layout]
    brims = [(x, y) for _, x, y, _ in layout]
    before = clearance_of(problem, mugs, np.array(brims))
    refined = refine(problem, mugs, brims, max_iterations=40)
    assert refined.clearance >= before
    assert refined.clearance == pytest.approx(clearance_of(problem, mugs, np.array(refined.brims)))
    if refined.clearance > 0:  # the distances are exact where the outlines keep apart
        assert refined.clearance == pytest.approx(
            shapely_clearance(problem, mugs, list(refined.brims)), abs=1e-6
        )


@settings(max_examples=30, deadline=None)
@given(brim_layouts)
def test_its_distances_are_the_packers_where_outlines_keep_apart(
    layout: list[tuple[str, float, float, float]],
) -> None:
    problem = replace(dataset_problem(1), footprint_kind="mug")
    mugs = [(t, rel) for t, _, _, rel in layout]
    bodies = [
        Bodies.build(
            MugOutline.of(problem.mug_types[t]),
            np.array([x]),
            np.array([y]),
            np.array([problem.handle_yaw_on_tray(x, y, rel)]),
        )
        for t, x, y, rel in layout
    ]
    walls = [float(2 * b.wall_gap(problem.tray_size_mm)[0]) for b in bodies]
    pairs = [float(a.gap_to(b, 0)[0]) for a, b in itertools.combinations(bodies, 2)]
    packer = min(walls + pairs)
    assert len(fixed_bodies(problem).cx) == 0
    mine = clearance_of(problem, mugs, np.array([(x, y) for _, x, y, _ in layout]))
    if packer > 0:
        assert mine == pytest.approx(packer, abs=1e-9)
    else:  # the packer's gaps stop at 0 where outlines touch or overlap; these go on below it
        assert mine <= 1e-9


def test_mugs_already_on_the_tray_are_refused_not_ignored() -> None:
    problem = replace(
        dataset_problem(1),
        footprint_kind="mug",
        placed=(TrayMug("p1", "small", 0, 0, False),),
    )
    with pytest.raises(ValueError, match="mugs already on the tray are not modelled"):
        refine(problem, [("big", 0.0)], [(200.0, 200.0)])
