"""A small typed CP-SAT model builder on OR-Tools' ``cp_model_helper`` (what ``exact`` uses).

``ortools.sat.python.cp_model`` imports pandas at its top for helpers dishbot does not use (0.2 s, a third
of a ``dishbot plan``); its model is a ``CpModelProto`` that ``cp_model_helper.SolveWrapper`` solves, and
``cp_model_helper`` itself loads in a fraction of that without pandas. This builder writes the same
protocol buffer ``cp_model`` writes for the same calls (variables and constraints in call order, the
same encodings: a test compares them), so the solver sees the same model and returns the same result.

Variables are their indices in the model (non-negative ints; only positive literals are used here).
OR-Tools 9.15 is the first release whose ``cp_model_helper`` holds the protocol buffers themselves.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from ortools.sat.python import cp_model_helper as cmh

_INT64_MIN = -(2**63)
_INT64_MAX = 2**63 - 1

Var = int


class Model:
    """A CP-SAT model: boolean and integer variables, the constraints below, one linear objective."""

    def __init__(self) -> None:
        self.proto = cmh.CpModelProto()

    def bool_var(self, name: str) -> Var:
        return self._var(name, (0, 1))

    def int_var(self, values: Iterable[int], name: str) -> Var:
        """A variable that takes one of ``values`` (any order, repeats allowed; at least one)."""
        ordered = sorted(set(values))
        if not ordered:
            raise ValueError(f"{name}: an integer variable needs at least one value")
        bounds: list[int] = []
        for v in ordered:
            if bounds and v == bounds[-1] + 1:
                bounds[-1] = v
            else:
                bounds += [v, v]
        return self._var(name, bounds)

    def _var(self, name: str, domain: Sequence[int]) -> Var:
        index = len(self.proto.variables)
        v = self.proto.variables.add()
        v.name = name
        v.domain.extend(domain)
        return index

    def at_most_one(self, literals: Iterable[Var]) -> None:
        self.proto.constraints.add().at_most_one.literals.extend(literals)

    def linear(self, terms: Iterable[tuple[int, Var]], lo: int, hi: int) -> None:
        """lo <= sum of coefficient * variable <= hi (``_INT64_MIN`` / ``_INT64_MAX``: no bound)."""
        c = self.proto.constraints.add().linear
        terms = _canonical(terms)
        c.vars.extend(v for _, v in terms)
        c.coeffs.extend(k for k, _ in terms)
        c.domain.extend((lo, hi))

    def at_most(self, terms: Iterable[tuple[int, Var]], hi: int) -> None:
        self.linear(terms, _INT64_MIN, hi)

    def equal(self, terms: Iterable[tuple[int, Var]], value: int) -> None:
        self.linear(terms, value, value)

    def implication(self, a: Var, b: Var) -> None:
        """a implies b (both literals)."""
        c = self.proto.constraints.add()
        c.enforcement_literal.append(a)
        c.bool_and.literals.append(b)

    def fixed_interval(self, start: int, size: int, name: str) -> int:
        """The interval [start, start + size): its index, for ``no_overlap_2d``."""
        return self._interval(name, None, start, size, None)

    def optional_interval(self, start: Var, size: int, present: Var, name: str) -> int:
        """The interval [start, start + size) (``start`` a variable) when ``present`` holds."""
        return self._interval(name, start, 0, size, present)

    def _interval(self, name: str, var: Var | None, offset: int, size: int, present: Var | None) -> int:
        index = len(self.proto.constraints)
        c = self.proto.constraints.add()
        c.name = name
        if present is not None:
            c.enforcement_literal.append(present)
        iv = c.interval
        for expr, extra in ((iv.start, 0), (iv.end, size)):
            if var is not None:
                expr.vars.append(var)
                expr.coeffs.append(1)
            expr.offset = offset + extra
        iv.size.offset = size
        return index

    def no_overlap_2d(self, x_intervals: Iterable[int], y_intervals: Iterable[int]) -> None:
        c = self.proto.constraints.add().no_overlap_2d
        c.x_intervals.extend(x_intervals)
        c.y_intervals.extend(y_intervals)

    def maximize(self, terms: Iterable[tuple[int, Var]]) -> None:
        """Maximise sum of coefficient * variable (replacing any objective before)."""
        self.proto.clear_objective()
        obj = self.proto.objective
        terms = _canonical(terms)
        obj.vars.extend(v for _, v in terms)
        obj.scaling_factor = -1.0  # CP-SAT minimises: the negated sum, scaled back by -1
        obj.coeffs.extend(-k for k, _ in terms)

    def hint(self, var: Var, value: int) -> None:
        self.proto.solution_hint.vars.append(var)
        self.proto.solution_hint.values.append(int(value))


def _canonical(terms: Iterable[tuple[int, Var]]) -> list[tuple[int, Var]]:
    """The terms with one coefficient per variable (none zero), by variable index, as ``cp_model`` writes
    a linear expression."""
    merged: dict[Var, int] = {}
    for k, v in terms:
        merged[v] = merged.get(v, 0) + k
    return [(k, v) for v, k in sorted(merged.items()) if k != 0]


@dataclass(frozen=True)
class Solution:
    """What a solve returned: ``status`` (``OPTIMAL``, ``FEASIBLE``, ...), the objective's value and its best
    proven bound, the solver's wall time (s), the deterministic time it spent (CP-SAT's unit of work, about
    a second of a typical machine's solving) and every variable's value (when a solution was found)."""

    status: str
    objective: float
    bound: float
    wall_time_s: float
    deterministic_time: float
    values: tuple[int, ...]

    @property
    def found(self) -> bool:
        return self.status in ("OPTIMAL", "FEASIBLE")

    def value(self, var: Var) -> int:
        return self.values[var]


# The least deterministic time a solve is given.
MIN_DETERMINISTIC_LIMIT = 0.01


def parameters(*, deterministic_limit: float, seed: int, workers: int = 1) -> cmh.SatParameters:
    """The solver's parameters: ``workers`` threads, seeded, stopping after ``deterministic_limit`` of
    deterministic time (``MIN_DETERMINISTIC_LIMIT`` at least) and never on the wall clock, so a solve cut
    short by its limit is cut at the same point of the same search however busy the machine is. (One
    worker: several would share their findings as they come, which depends on the threads' timing.)"""
    p = cmh.SatParameters()
    p.num_workers = workers
    p.random_seed = seed
    p.max_deterministic_time = max(deterministic_limit, MIN_DETERMINISTIC_LIMIT)
    return p


def solve(model: Model, *, deterministic_limit: float, seed: int, workers: int = 1) -> Solution:
    """Solves ``model`` with ``parameters(...)``: the result is the same on a busy machine as on an idle
    one."""
    wrapper = cmh.SolveWrapper()
    wrapper.set_parameters(parameters(deterministic_limit=deterministic_limit, seed=seed, workers=workers))
    response: cmh.CpSolverResponse = wrapper.solve(model.proto)  # type: ignore[no-untyped-call]
    status = str(response.status.name)
    return Solution(
        status,
        float(response.objective_value),
        float(response.best_objective_bound),
        float(response.wall_time),
        float(response.deterministic_time),
        tuple(int(v) for v in response.solution) if status in ("OPTIMAL", "FEASIBLE") else (),
    )
