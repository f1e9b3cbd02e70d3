"""The cost model: Eq 4.7 weights, normalisation, the two fitness methods, sortedness."""

from __future__ import annotations

import math

import pytest

from description import thesis
from planning.placement import ThesisMoveCost, dataset_problem
from planning.placement.cost import (
    CostFunction,
    Evaluator,
    Fitness,
    FitnessMethod,
    Metrics,
    sortedness,
    weights_from_ranks,
)
from planning.placement.heuristics import Heuristic
from planning.placement.packing import Packer


def test_eq_4_7_on_the_survey_counts_gives_the_overall_weights_of_table_5_3() -> None:
    weights = weights_from_ranks(thesis.SURVEY_RANK_COUNTS)
    assert {p: round(w, 3) for p, w in weights.items()} == thesis.SURVEY_OVERALL_WEIGHTS
    assert thesis.SURVEY_OVERALL_WEIGHTS == {"n": 0.338, "E": 0.258, "t": 0.252, "s": 0.152}


def test_thesis_move_cost_is_potential_energy_over_the_straight_distance() -> None:
    seconds, joules = ThesisMoveCost(arm_speed_m_s=0.1)(0.2, (0.0, 0.0), (0.3, 0.4))
    assert seconds == pytest.approx(5.0)
    assert joules == pytest.approx(0.2 * 9.81 * 0.5)


def test_weighted_sum_uses_eq_5_2_weights_on_running_normalised_parameters() -> None:
    f = Fitness.build(FitnessMethod.WS, CostFunction.UPC)
    worst, best = Metrics(4, 100.0, 10.0, 50.0, 0), Metrics(8, 200.0, 2.0, 10.0, 1)
    f.norm.observe(worst)
    f.norm.observe(best)
    assert f.value(best) == pytest.approx(0.0)
    assert f.value(worst) == pytest.approx(0.37 + 0.28 + 0.27 + 0.08)
    mid = Metrics(6, 150.0, 6.0, 30.0, 1)
    assert f.value(mid) == pytest.approx(0.37 * 0.5 + 0.28 * 0.5 + 0.27 * 0.5)


def test_ranking_fitness_prefers_more_mugs_then_more_area_then_less_energy() -> None:
    f = Fitness.build(FitnessMethod.RF, CostFunction.UPC)
    a = Metrics(8, 100.0, 9.0, 50.0, 0)
    b = Metrics(7, 300.0, 1.0, 10.0, 1)
    c = Metrics(8, 120.0, 9.5, 60.0, 0)
    d = Metrics(8, 120.0, 9.0, 60.0, 0)
    for m in (a, b, c, d):
        f.norm.observe(m)
    assert f.better(a, b)
    assert f.better(c, a)
    assert f.better(d, c)


def test_bin_packing_ranking_ignores_energy() -> None:
    f = Fitness.build(FitnessMethod.RF, CostFunction.BPC)
    a, b = Metrics(8, 100.0, 9.0, 50.0, 0), Metrics(8, 100.0, 1.0, 10.0, 1)
    f.norm.observe(a)
    f.norm.observe(b)
    assert not f.better(b, a)
    assert not f.better(a, b)


def test_user_ranking_keeps_area_right_after_the_mug_count() -> None:
    f = Fitness.build(FitnessMethod.RF, CostFunction.UPC, ranking=("E", "n", "t", "s"))
    assert f.ranking == ("E", "n", "A", "t", "s")


def test_engineering_cost_drops_sortedness() -> None:
    f = Fitness.build(FitnessMethod.WS, CostFunction.EC, weights={"n": 0.5, "E": 0.2, "t": 0.2, "s": 0.1})
    assert f.weights["s"] == 0.0
    assert "s" not in Fitness.build(FitnessMethod.RF, CostFunction.EC).ranking


def test_sortedness_is_one_only_for_size_sorted_orders() -> None:
    p = dataset_problem(1)
    big = [i for i, m in enumerate(p.mugs) if m.type == "big"]
    small = [i for i, m in enumerate(p.mugs) if m.type == "small"]
    assert sortedness(p, big + small) == 1
    assert sortedness(p, small + big) == 1
    assert sortedness(p, [big[0], small[0], big[1]]) == 0


def test_evaluator_sums_area_energy_and_time_of_the_placed_mugs() -> None:
    p = dataset_problem(1)
    packing = Packer(p, Heuristic.LTF).pack(range(len(p.mugs)))
    m = Evaluator(p).metrics(packing)
    assert m.n == packing.n
    areas = [math.prod(p.footprint(p.mugs[i].type)) for i in packing.placed]
    assert sum(areas) == m.A
    spots = packing.spot_of()
    dist = {}
    for i in packing.placed:
        mug = p.mugs[i]
        cx, cy = p.to_world_mm(*p.brim_centre_on_tray(mug.type, spots[i][0], spots[i][1]))
        dist[i] = math.dist((mug.x_mm, mug.y_mm), (cx, cy)) / 1000.0
    energy = sum(p.mug_types[p.mugs[i].type].mass_kg * 9.81 * d for i, d in dist.items())
    assert pytest.approx(energy) == m.E
    assert m.t == pytest.approx(sum(dist.values()) / p.arm_speed_m_s)
