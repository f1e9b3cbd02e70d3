"""What one planning run shares, for every method: the options, the context (problem, packers, fitness,
RNG, start time) and what a method returns (``Candidate``). The methods import this module; the planner
(``planner.py``) imports the methods, so nothing imports back."""

from __future__ import annotations

import random
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TypeVar

from planning.placement.cost import CostFunction, Evaluator, Fitness, FitnessMethod, Metrics, MoveCost
from planning.placement.errors import InvalidProblem
from planning.placement.heuristics import Heuristic, parse_heuristic
from planning.placement.packing import Packer, Packing
from planning.placement.problem import Problem
from planning.placement.sorts import Sort, parse_sort, sorted_order


@dataclass(frozen=True)
class PlanOptions:
    """How to plan. ``sort`` None means the method's default (BH tries every deterministic sort; the
    metaheuristics start from non-increasing length, the thesis's recommendation in §5.3.2)."""

    method: str = "auto"
    heuristic: str = "ltf"
    sort: str | None = None
    fitness: str = "rf"
    cost: str = "upc"
    seed: int = 0
    time_limit_s: float = 1.0
    weights: Mapping[str, float] | None = None
    ranking: tuple[str, ...] | None = None
    move_cost: MoveCost | None = field(default=None, compare=False)
    # Where the planner keeps work between runs (``cache``: proven rectangle optima, scan orders; ``dishbot
    # plan`` gives its cache folder). None: do it every time. The same plan either way.
    cache_dir: Path | None = field(default=None, compare=False)


# (mug index, x, y, rotated) in the order the method packed them
Layout = tuple[tuple[int, int, int, bool], ...]


@dataclass(frozen=True)
class Candidate:
    """What a method returns before it is turned into a ``PlanResult``."""

    layout: Layout
    optimal: bool | None = None
    upper_bound: int | None = None
    status: str = "feasible"
    notes: tuple[str, ...] = ()

    @staticmethod
    def of(packing: Packing) -> Candidate:
        spots = packing.spot_of()
        return Candidate(tuple((m, *spots[m]) for m in packing.placed))


class Context:
    """Everything one planning run shares: the problem, a packer per heuristic, the fitness and the RNG."""

    def __init__(self, problem: Problem, options: PlanOptions) -> None:
        self.problem = problem
        self.options = options
        self.heuristic = _parse(parse_heuristic, options.heuristic, "heuristic")
        self.sort = None if options.sort is None else _parse(parse_sort, options.sort, "sort")
        _check_preferences(options)
        self.fitness = Fitness.build(
            _parse(_enum_parser(FitnessMethod, "fitness method"), options.fitness, "fitness"),
            _parse(_enum_parser(CostFunction, "cost function"), options.cost, "cost"),
            weights=options.weights,
            ranking=options.ranking,
        )
        self.evaluator = Evaluator(problem, options.move_cost)
        self.rng = random.Random(options.seed)
        self.started = time.perf_counter()
        self._packers: dict[Heuristic, Packer] = {}
        self.evaluations = 0

    def packer(self, heuristic: Heuristic | None = None) -> Packer:
        h = heuristic or self.heuristic
        if h not in self._packers:
            self._packers[h] = Packer(self.problem, h)
        return self._packers[h]

    def evaluate(self, packing: Packing) -> Metrics:
        """The packing's parameters, also widening the running normalisation."""
        m = self.evaluator.metrics(packing)
        self.fitness.norm.observe(m)
        self.evaluations += 1
        return m

    def initial_order(self, default: Sort = Sort.NIS_L) -> list[int]:
        return sorted_order(self.problem, self.sort or default, self.rng)

    def elapsed(self) -> float:
        return time.perf_counter() - self.started


def _check_preferences(options: PlanOptions) -> None:
    """A user's own weights (Eq 4.6) or ranking (§4.2.1.5) must name the cost parameters."""
    if options.weights is not None:
        for name, w in options.weights.items():
            if name not in ("n", "E", "t", "s"):
                raise InvalidProblem(f"weights: unknown parameter {name!r} (known: n, E, t, s)")
            if isinstance(w, bool) or not isinstance(w, int | float) or not 0 <= w < float("inf"):
                raise InvalidProblem(f"weights.{name}: must be a number, 0 or more, got {w!r}")
        if not any(options.weights.values()):
            raise InvalidProblem("weights: at least one weight must be positive")
    if options.ranking is not None:
        for name in options.ranking:
            if name not in ("n", "A", "E", "t", "s"):
                raise InvalidProblem(f"ranking: unknown parameter {name!r} (known: n, A, E, t, s)")
        if len(set(options.ranking)) != len(options.ranking):
            raise InvalidProblem(f"ranking: a parameter appears twice in {','.join(options.ranking)}")


_T = TypeVar("_T")
_E = TypeVar("_E", bound=StrEnum)


def _enum_parser(enum: type[_E], what: str) -> Callable[[str], _E]:
    def parse(value: str) -> _E:
        try:
            return enum(value.lower())
        except ValueError as e:
            known = ", ".join(m.value for m in enum)
            raise ValueError(f"unknown {what} {value!r} (known: {known})") from e

    return parse


def _parse(parser: Callable[[str], _T], value: str, name: str) -> _T:
    try:
        return parser(value)
    except ValueError as e:
        raise InvalidProblem(f"{name}: {e}") from e
