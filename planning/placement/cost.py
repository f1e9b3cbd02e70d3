"""The cost model of §4.2.1: placement parameters, running normalisation, and the two fitness methods.

Parameters of a placement (φ): number of mugs placed n, covered area A (footprints with tolerance, Eq 4.4),
energy E (Eq 4.2) and time t (Eq 4.5) from a ``MoveCost``, and sortedness s. The computation time t_c of
Eq 4.5 is the same for every candidate compared within one iteration, so comparisons use the motion part only
and t_c is added once to the reported t; that also keeps a seeded run deterministic.

Each parameter is normalised by the smallest and largest value seen so far in the run (Eq 4.2-4.5); costs are
always recomputed from the raw parameters, so a widened range re-scores earlier solutions as the thesis does.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

from description import thesis
from planning.placement.packing import Packing
from planning.placement.problem import Problem


class MoveCost(Protocol):
    """Time and energy to carry one mug from the counter to its tray spot."""

    def __call__(
        self, mug_mass_kg: float, start_xy_m: tuple[float, float], goal_xy_m: tuple[float, float]
    ) -> tuple[float, float]:
        """Returns (seconds, joules)."""
        ...


@dataclass(frozen=True, slots=True)
class ThesisMoveCost:
    """The thesis's proxies: E = M·g·Δm (Eq 4.2) and time Δm / V_a (Eq 4.5), Δm the straight-line distance."""

    arm_speed_m_s: float

    def __call__(
        self, mug_mass_kg: float, start_xy_m: tuple[float, float], goal_xy_m: tuple[float, float]
    ) -> tuple[float, float]:
        dm = math.dist(start_xy_m, goal_xy_m)
        return dm / self.arm_speed_m_s, mug_mass_kg * thesis.GRAVITY_M_S2 * dm


class FitnessMethod(StrEnum):
    WS = "ws"  # weighted sum, Eq 4.6
    RF = "rf"  # ranking fitness, Eq 4.11 / 5.4 / 5.5


class CostFunction(StrEnum):
    BPC = "bpc"  # bin-packing cost
    UPC = "upc"  # user preference-based cost
    EC = "ec"  # engineering cost (no sortedness)


PARAMS = ("n", "A", "E", "t", "s")


@dataclass(frozen=True, slots=True)
class Metrics:
    """Raw placement parameters φ of one layout (t without the computation time)."""

    n: int
    A: float
    E: float
    t: float
    s: int


def weights_from_ranks(counts: Mapping[str, Sequence[int]]) -> dict[str, float]:
    """Eq 4.7: W_i = Σ_j R_ij (N - j + 1) / Σ_i Σ_j R_ij (N - j + 1); "not important" answers carry no weight.

    ``counts[param][j]`` is the number of answers ranking ``param`` at rank j + 1."""
    N = len(counts)
    score = {p: sum(r * (N - j) for j, r in enumerate(ranks[:N])) for p, ranks in counts.items()}
    total = sum(score.values())
    if total <= 0:
        raise ValueError("ranks: at least one parameter must be ranked")
    return {p: v / total for p, v in score.items()}


def default_weights(cost: CostFunction) -> dict[str, float]:
    """Eq 5.1-5.3."""
    if cost is CostFunction.BPC:
        return {"n": 1.0, "E": 0.0, "t": 0.0, "s": 0.0}
    return dict(thesis.UPC_WEIGHTS if cost is CostFunction.UPC else thesis.EC_WEIGHTS)


def default_ranking(cost: CostFunction) -> tuple[str, ...]:
    """§5.2.6: n (with A right after it), then E, t, s; BPC compares n and A only, EC drops s."""
    if cost is CostFunction.BPC:
        return ("n", "A")
    return thesis.RF_RANKING if cost is CostFunction.UPC else tuple(p for p in thesis.RF_RANKING if p != "s")


_NORMALISED = {"n": 0, "A": 1, "E": 2, "t": 3}


class Normaliser:
    """Running minimum and maximum of n, A, E and t over every layout seen in one run."""

    __slots__ = ("high", "low")

    def __init__(self) -> None:
        self.low = [math.inf] * 4
        self.high = [-math.inf] * 4

    def observe(self, m: Metrics) -> None:
        low, high = self.low, self.high
        for i, v in enumerate((m.n, m.A, m.E, m.t)):
            if v < low[i]:
                low[i] = v
            if v > high[i]:
                high[i] = v

    def scaled(self, p: str, v: float) -> float:
        """(v - min) / (max - min), 0 while the range is empty."""
        i = _NORMALISED[p]
        lo = self.low[i]
        span = self.high[i] - lo
        return (v - lo) / span if span > 0 else 0.0


@dataclass
class Fitness:
    """Scores layouts under one fitness method and cost function; lower is better."""

    method: FitnessMethod
    cost: CostFunction
    weights: dict[str, float]
    ranking: tuple[str, ...]
    norm: Normaliser = field(default_factory=Normaliser)
    _raw: Callable[[Metrics], tuple[float, ...]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._raw = _ranking_key(self.ranking)

    @classmethod
    def build(
        cls,
        method: FitnessMethod,
        cost: CostFunction,
        *,
        weights: Mapping[str, float] | None = None,
        ranking: Sequence[str] | None = None,
    ) -> Fitness:
        w = default_weights(cost) if weights is None else {p: float(weights.get(p, 0.0)) for p in "nEts"}
        if cost is CostFunction.EC:
            w["s"] = 0.0
        r = default_ranking(cost) if ranking is None else _with_area(tuple(ranking), cost)
        return cls(method, cost, w, r)

    def components(self, m: Metrics) -> dict[str, float]:
        """The cost parameters C⃗: (1 - n'), (1 - A'), E', t', (1 - s)."""
        nz = self.norm.scaled
        return {
            "n": 1.0 - nz("n", m.n),
            "A": 1.0 - nz("A", m.A),
            "E": nz("E", m.E),
            "t": nz("t", m.t),
            "s": 1.0 - m.s,
        }

    def key(self, m: Metrics) -> tuple[float, ...]:
        """Sort key, lower is better: the weighted cost (WS), or the ranked parameters (RF).

        Normalisation is monotone, so ranking the raw parameters (signed so that lower is better) orders
        layouts exactly as ranking the normalised cost parameters does, without rescaling on every compare."""
        if self.method is FitnessMethod.WS:
            return (self.weighted(m),)
        return self._raw(m)

    def weighted(self, m: Metrics) -> float:
        """Eq 4.6 (with Eq 4.8-4.10 as weight choices)."""
        w, nz = self.weights, self.norm.scaled
        return (
            w["n"] * (1.0 - nz("n", m.n))
            + w["E"] * nz("E", m.E)
            + w["t"] * nz("t", m.t)
            + w["s"] * (1.0 - m.s)
        )

    def value(self, m: Metrics) -> float:
        """One number: the weighted cost (WS) or the mean ranked cost parameter (RF; SA's "energy")."""
        if self.method is FitnessMethod.WS:
            return self.weighted(m)
        c = self.components(m)
        return sum(c[p] for p in self.ranking) / len(self.ranking)

    def better(self, a: Metrics, b: Metrics) -> bool:
        """IsCostDecreased(a, b)."""
        return self.key(a) < self.key(b)


# Each parameter signed so that lower is better, for ranking comparisons.
_RAW_COST: dict[str, Callable[[Metrics], float]] = {
    "n": lambda m: -m.n,
    "A": lambda m: -m.A,
    "E": lambda m: m.E,
    "t": lambda m: m.t,
    "s": lambda m: -m.s,
}


def _ranking_key(ranking: tuple[str, ...]) -> Callable[[Metrics], tuple[float, ...]]:
    """The raw ranking key; the thesis's orders get a direct function (it is called millions of times)."""
    if ranking == ("n", "A", "E", "t", "s"):
        return lambda m: (-m.n, -m.A, m.E, m.t, -m.s)
    if ranking == ("n", "A", "E", "t"):
        return lambda m: (-m.n, -m.A, m.E, m.t)
    if ranking == ("n", "A"):
        return lambda m: (-m.n, -m.A)
    getters = tuple(_RAW_COST[p] for p in ranking)
    return lambda m: tuple([get(m) for get in getters])


def _with_area(ranking: tuple[str, ...], cost: CostFunction) -> tuple[str, ...]:
    for p in ranking:
        if p not in PARAMS:
            raise ValueError(f"ranking: unknown parameter {p!r} (known: {', '.join(PARAMS)})")
    out = [p for p in ranking if p != "A" and not (cost is CostFunction.EC and p == "s")]
    if "n" in out:
        out.insert(out.index("n") + 1, "A")
    return tuple(out)


def sortedness(problem: Problem, mugs_in_order: Sequence[int]) -> int:
    """1 if the placed mugs, in order, are sorted by width or by length (either direction), else 0."""
    types = problem.mug_types
    widths = [types[problem.mugs[i].type].width_mm for i in mugs_in_order]
    lengths = [types[problem.mugs[i].type].diameter_mm for i in mugs_in_order]
    return size_sorted(widths, lengths)


def size_sorted(widths: Sequence[int], lengths: Sequence[int]) -> int:
    """s of §4.2.1.4 for a sequence of mug sizes: 1 if monotone in width or in length, else 0."""
    for seq in (widths, lengths):
        pairs = list(itertools.pairwise(seq))
        if all(a >= b for a, b in pairs) or all(a <= b for a, b in pairs):
            return 1
    return 0


class Evaluator:
    """Computes the placement parameters of packings, caching each mug's move cost per tray spot."""

    def __init__(self, problem: Problem, move_cost: MoveCost | None = None) -> None:
        self.problem = problem
        self.move_cost: MoveCost = move_cost or ThesisMoveCost(problem.arm_speed_m_s)
        self._moves: dict[tuple[int, int, int, bool], tuple[float, float]] = {}
        self._area = [math.prod(problem.footprint(m.type)) for m in problem.mugs]

    def area(self, mug: int) -> float:
        """The mug's footprint area with tolerance (mm²), the same in both orientations."""
        return self._area[mug]

    def move(self, mug: int, x: int, y: int, rotated: bool) -> tuple[float, float]:
        """(seconds, joules) to carry mug ``mug`` to the footprint corner (x, y)."""
        key = (mug, x, y, rotated)
        hit = self._moves.get(key)
        if hit is None:
            p = self.problem
            m = p.mugs[mug]
            cx, cy = p.to_world_mm(*p.brim_centre_on_tray(m.type, x, y))
            hit = self.move_cost(
                p.mug_types[m.type].mass_kg, (m.x_mm / 1000.0, m.y_mm / 1000.0), (cx / 1000.0, cy / 1000.0)
            )
            self._moves[key] = hit
        return hit

    def metrics(self, packing: Packing) -> Metrics:
        seconds = joules = area = 0.0
        placed = []
        for mug, spot in zip(packing.order, packing.spots, strict=True):
            if spot is None:
                continue
            placed.append(mug)
            dt, de = self.move(mug, *spot)
            seconds += dt
            joules += de
            area += self._area[mug]
        return Metrics(len(placed), area, joules, seconds, sortedness(self.problem, placed))

    def metrics_of_layout(self, layout: Sequence[tuple[int, int, int, bool]]) -> Metrics:
        """Parameters of an explicit layout [(mug, x, y, rotated)] in execution order."""
        seconds = joules = area = 0.0
        for mug, x, y, rot in layout:
            dt, de = self.move(mug, x, y, rot)
            seconds += dt
            joules += de
            area += self._area[mug]
        return Metrics(len(layout), area, joules, seconds, sortedness(self.problem, [m[0] for m in layout]))
