"""A plan does not depend on how busy the machine was (issue 22): the CP-SAT solves stop on deterministic
time, never on the wall clock, and ``auto`` reads no clock to share its budget out."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import pytest
from ortools.sat.python import cp_model_helper as cmh

from planning.placement import PlanOptions, cpsat, dataset_problem, plan
from planning.placement import context as context_module

_SEEN: list[Any] = []


class _Recording:
    """``cp_model_helper.SolveWrapper`` that keeps the parameters each solve was given in ``_SEEN``."""

    def __init__(self) -> None:
        self._wrapper = cmh.SolveWrapper()

    def set_parameters(self, parameters: Any) -> None:
        _SEEN.append(parameters)
        self._wrapper.set_parameters(parameters)

    def solve(self, proto: Any) -> Any:
        return self._wrapper.solve(proto)  # type: ignore[no-untyped-call]


@pytest.mark.parametrize("footprint", ["rect", "mug"])
def test_every_solve_stops_on_deterministic_time_on_one_seeded_thread(
    monkeypatch: pytest.MonkeyPatch, footprint: str
) -> None:
    proxy = SimpleNamespace(SatParameters=cmh.SatParameters, CpModelProto=cmh.CpModelProto)
    proxy.SolveWrapper = _Recording
    monkeypatch.setattr(cpsat, "cmh", proxy)
    _SEEN.clear()
    problem = replace(dataset_problem(2), footprint_kind=footprint)
    plan(problem, PlanOptions(seed=7, time_limit_s=1.0))
    seen = list(_SEEN)
    assert len(seen) == 2  # both phases of the rectangle optimum (the mug packer's start, for "mug")
    for p in seen:
        assert p.max_time_in_seconds == math.inf  # no wall-clock limit: CP-SAT's default, never set
        assert 0.01 <= p.max_deterministic_time <= 1.0
        assert (p.num_workers, p.random_seed) == (1, 7)
    # phase 1 gets the exact model's share of the budget, phase 2 what phase 1 left of it
    assert seen[0].max_deterministic_time == pytest.approx((1.0 - 0.02) * 0.6)
    assert seen[1].max_deterministic_time < seen[0].max_deterministic_time


class _BusyClock:
    """``time`` as a very busy machine sees it: every reading of the clock is 5 s after the one before."""

    def __init__(self) -> None:
        self.now = time.perf_counter()

    def perf_counter(self) -> float:
        self.now += 5.0
        return self.now


@pytest.mark.parametrize(("dataset", "footprint"), [(2, "rect"), (5, "rect"), (2, "mug")])
def test_a_busy_machine_gets_the_plan_an_idle_one_gets(
    monkeypatch: pytest.MonkeyPatch, dataset: int, footprint: str
) -> None:
    problem = replace(dataset_problem(dataset), footprint_kind=footprint)
    idle = plan(problem, PlanOptions()).to_json()
    monkeypatch.setattr(context_module, "time", _BusyClock())
    busy = plan(problem, PlanOptions()).to_json()
    # the clock did run slow: a wall-clock budget would have been spent
    assert float(str(busy["wall_time_s"])) > 1.0
    for doc in (idle, busy):
        del doc["wall_time_s"], doc["t"]  # what the run took is reported; nothing else may change
    assert busy == idle
    assert idle["optimal"] is True or footprint == "mug"
    assert idle["n"] == {(2, "rect"): 8, (5, "rect"): 20, (2, "mug"): 11}[(dataset, footprint)]
