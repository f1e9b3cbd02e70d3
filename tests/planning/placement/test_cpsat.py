"""The CP-SAT model builder (``planning.placement.cpsat``, on ``cp_model_helper`` without pandas) writes the
model OR-Tools' own ``cp_model`` writes for the same calls, and ``exact`` finds the same optimum with it."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace
from typing import Any

import pytest
from ortools.sat.python import cp_model

from planning.placement import cpsat, dataset_problem, exact


class CpModelBuilder:
    """``cpsat.Model``'s calls made on ``cp_model.CpModel`` (variables as their indices)."""

    def __init__(self) -> None:
        self.model = cp_model.CpModel()
        self.vars: list[Any] = []
        self.intervals: dict[int, Any] = {}

    @property
    def proto(self) -> Any:
        return self.model.proto

    def _new(self, v: Any) -> int:
        self.vars.append(v)
        return int(v.index)

    def bool_var(self, name: str) -> int:
        return self._new(self.model.new_bool_var(name))

    def int_var(self, values: Iterable[int], name: str) -> int:
        return self._new(self.model.new_int_var_from_domain(cp_model.Domain.from_values(list(values)), name))

    def _sum(self, terms: Iterable[tuple[int, int]]) -> Any:
        return sum(k * self.vars[v] for k, v in terms)

    def at_most_one(self, literals: Iterable[int]) -> None:
        self.model.add_at_most_one([self.vars[v] for v in literals])

    def at_most(self, terms: Iterable[tuple[int, int]], hi: int) -> None:
        self.model.add(self._sum(terms) <= hi)

    def equal(self, terms: Iterable[tuple[int, int]], value: int) -> None:
        self.model.add(self._sum(terms) == value)

    def implication(self, a: int, b: int) -> None:
        self.model.add_implication(self.vars[a], self.vars[b])

    def fixed_interval(self, start: int, size: int, name: str) -> int:
        iv = self.model.new_fixed_size_interval_var(start, size, name)
        self.intervals[int(iv.index)] = iv
        return int(iv.index)

    def optional_interval(self, start: int, size: int, present: int, name: str) -> int:
        iv = self.model.new_optional_fixed_size_interval_var(self.vars[start], size, self.vars[present], name)
        self.intervals[int(iv.index)] = iv
        return int(iv.index)

    def no_overlap_2d(self, xs: Iterable[int], ys: Iterable[int]) -> None:
        self.model.add_no_overlap_2d([self.intervals[i] for i in xs], [self.intervals[i] for i in ys])

    def maximize(self, terms: Iterable[tuple[int, int]]) -> None:
        self.model.maximize(self._sum(terms))

    def hint(self, var: int, value: int) -> None:
        self.model.add_hint(self.vars[var], bool(value))


CASES = [(n, False) for n in range(1, 7)] + [(2, True), (5, True)]


@pytest.mark.parametrize(("n", "rotation"), CASES, ids=[f"ds{n}{'-rot' if r else ''}" for n, r in CASES])
def test_both_builders_write_the_same_model_and_find_the_same_optimum(
    monkeypatch: pytest.MonkeyPatch, n: int, rotation: bool
) -> None:
    problem = replace(dataset_problem(n), allow_rotation=rotation)
    seen: list[str] = []
    solve = cpsat.solve

    def recording(model: Any, **kw: Any) -> cpsat.Solution:
        seen.append(str(model.proto))
        return solve(model, **kw)

    # The point model proves its optimum in well under a second; the box model of the rotated 30-mug
    # datasets runs to its limit (deterministic time: the same point of the same search in both runs).
    limit = 2.0 if rotation else 30.0
    monkeypatch.setattr(cpsat, "solve", recording)
    ours = exact.solve(problem, deterministic_limit=limit, seed=0)
    ours_models = list(seen)
    seen.clear()
    monkeypatch.setattr(cpsat, "Model", CpModelBuilder)
    theirs = exact.solve(problem, deterministic_limit=limit, seed=0)
    assert ours_models == seen
    assert ours_models  # a model was solved
    if not rotation:
        assert (ours.optimal, theirs.optimal) == (True, True)
    # The same model, seed and deterministic limit: the same search, cut at the same point however busy the
    # machine is, so the same spots and bound even where the limit cuts it short (the rotated 30-mug cases).
    assert (ours.spots, ours.upper_bound, ours.optimal) == (theirs.spots, theirs.upper_bound, theirs.optimal)


def test_a_solution_reads_its_values_and_an_integer_domain_is_its_values() -> None:
    m = cpsat.Model()
    a, b = m.bool_var("a"), m.bool_var("b")
    x = m.int_var([9, 3, 4, 0, 3], "x")
    assert list(m.proto.variables[x].domain) == [0, 0, 3, 4, 9, 9]
    m.at_most_one([a, b])
    m.implication(a, b)
    m.maximize([(1, a), (2, b), (1, x)])
    s = cpsat.solve(m, deterministic_limit=1.0, seed=0)
    assert (s.status, s.objective, s.bound) == ("OPTIMAL", 11.0, 11.0)
    assert (s.value(a), s.value(b), s.value(x)) == (0, 1, 9)
    with pytest.raises(ValueError, match="x: an integer variable needs at least one value"):
        m.int_var([], "x")
