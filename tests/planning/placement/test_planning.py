"""plan(): every method's layout is valid; exact and auto prove the optimum; replanning, rotation."""

from __future__ import annotations

import dataclasses

import pytest

from planning.placement import (
    METHODS,
    InvalidProblem,
    PlanOptions,
    PlanResult,
    Problem,
    TrayMug,
    dataset_problem,
    plan,
)
from planning.placement.order import blocking_violations

ALL_METHODS = ("bh", "sa", "ga", "psop-n", "psop-i", "psok-n", "psok-i", "exact", "auto")


def assert_valid(problem: Problem, result: PlanResult) -> None:
    """Inside the tray, apart from each other and from the mugs already there, each counter mug once,
    in an order that never reaches over a placed mug."""
    as_fixed = [TrayMug(p.id, p.type, p.x_mm, p.y_mm, p.rotated) for p in result.placed]
    dataclasses.replace(problem, mugs=(), placed=problem.placed + tuple(as_fixed))  # validates
    ids = [p.id for p in result.placed] + list(result.unplaced)
    assert sorted(ids) == sorted(m.id for m in problem.mugs)
    assert [p.order for p in result.placed] == list(range(1, len(result.placed) + 1))
    footprints = [
        (k, p.x_mm, p.y_mm, *problem.footprint(p.type, p.rotated)) for k, p in enumerate(result.placed)
    ]
    assert blocking_violations(footprints) == []
    assert result.n == len(result.placed)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_every_method_gives_a_valid_layout_on_dataset_1(method: str) -> None:
    problem = dataset_problem(1)
    assert_valid(problem, plan(problem, PlanOptions(method=method)))


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_exact_proves_the_optimum_and_auto_reaches_it_within_a_second(n: int) -> None:
    problem = dataset_problem(n)
    exact = plan(problem, PlanOptions(method="exact", time_limit_s=5.0))
    assert exact.optimal is True
    assert exact.upper_bound == exact.n
    auto = plan(problem, PlanOptions(method="auto", time_limit_s=1.0))
    assert auto.n == exact.n
    assert auto.optimal is True
    assert_valid(problem, auto)
    assert exact.n >= plan(problem, PlanOptions(method="bh")).n


def test_optimum_beats_the_thesis_best_on_the_full_tray() -> None:
    assert [plan(dataset_problem(n), PlanOptions(method="exact")).n for n in (4, 5, 6)] == [18, 20, 23]


@pytest.mark.parametrize("method", ["sa", "ga", "psop-n", "psop-i", "psok-n", "psok-i"])
def test_seeded_runs_repeat_exactly(method: str) -> None:
    full = dataset_problem(2)
    problem = dataclasses.replace(full, mugs=full.mugs[:8])
    runs = [plan(problem, PlanOptions(method=method, sort="ro", seed=7)) for _ in range(2)]
    layouts = [(r.placed, r.unplaced) for r in runs]
    assert layouts[0] == layouts[1]
    assert runs[0].evaluations == runs[1].evaluations


@pytest.mark.parametrize("method", ["bh", "sa", "exact", "auto"])
def test_replanning_keeps_clear_of_mugs_already_on_the_tray(method: str) -> None:
    base = dataset_problem(1)
    first = plan(base, PlanOptions(method="bh"))
    kept = first.placed[:4]
    on_tray = tuple(TrayMug(p.id, p.type, p.x_mm, p.y_mm, p.rotated) for p in kept)
    rest = tuple(m for m in base.mugs if m.id not in {p.id for p in kept})
    problem = dataclasses.replace(base, mugs=rest, placed=on_tray)
    result = plan(problem, PlanOptions(method=method))
    assert_valid(problem, result)
    assert not {p.id for p in result.placed} & {q.id for q in on_tray}


def test_rotation_fits_more_mugs_when_the_arm_can_turn_them() -> None:
    fixed = dataset_problem(2)
    turning = dataclasses.replace(fixed, allow_rotation=True)
    upright = plan(fixed, PlanOptions(method="exact"))
    rotated = plan(turning, PlanOptions(method="exact", time_limit_s=5.0))
    assert rotated.n > upright.n
    assert any(p.rotated for p in rotated.placed)
    assert_valid(turning, rotated)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (PlanOptions(method="magic"), "method: unknown method 'magic' (known: " + ", ".join(METHODS) + ")"),
        (
            PlanOptions(heuristic="zigzag"),
            "heuristic: unknown heuristic 'zigzag' (known: blf, lbf, tlf, ltf, brf, rbf, trf, rtf)",
        ),
        (PlanOptions(sort="size"), "sort: unknown sort 'size' (known: cif, nis-l, nis-w, nds-l, nds-w, ro)"),
        (PlanOptions(fitness="best"), "fitness: unknown fitness method 'best' (known: ws, rf)"),
        (PlanOptions(cost="cheap"), "cost: unknown cost function 'cheap' (known: bpc, upc, ec)"),
        (PlanOptions(time_limit_s=0), "time_limit_s: must be positive, got 0"),
    ],
)
def test_bad_options_name_the_option(options: PlanOptions, message: str) -> None:
    with pytest.raises(InvalidProblem) as e:
        plan(dataset_problem(1), options)
    assert str(e.value) == message


def test_result_json_holds_the_documented_fields() -> None:
    doc = plan(dataset_problem(1), PlanOptions(method="auto")).to_json()
    for key in ("method", "seed", "wall_time_s", "placed", "unplaced", "n", "A", "E", "t", "s", "cost"):
        assert key in doc
    assert doc["optimal"] is True
    assert doc["upper_bound"] == doc["n"] == 10
    first = doc["placed"][0]  # type: ignore[index]
    assert set(first) == {"id", "type", "x_mm", "y_mm", "rotated", "order", "brim_mm", "handle_yaw_rad"}


def test_slots_give_brim_centres_in_the_world_frame_in_placing_order() -> None:
    problem = dataset_problem(1)
    result = plan(problem, PlanOptions(method="bh"))
    slots = result.slots(problem)
    assert [s.mug_id for s in slots] == [p.id for p in result.placed]
    first = result.placed[0]
    r = (problem.mug_types[first.type].diameter_mm + problem.tolerance_mm) / 2
    assert slots[0].x_m == pytest.approx((problem.tray_origin_mm[0] + first.x_mm + r) / 1000)
    assert slots[0].y_m == pytest.approx((problem.tray_origin_mm[1] + first.y_mm + r) / 1000)
