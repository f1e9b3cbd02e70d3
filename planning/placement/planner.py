"""``plan()``: one entry point for every placement method; returns a layout, its cost and a placing order.

A pure computation: it logs nothing (the caller, e.g. the daemon's ``plan`` state, logs the outcome with its
own context) and so never writes to stdout, which ``dishbot plan --json`` reserves for the result."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TypeVar

from planning.interfaces import TraySlot
from planning.placement.context import Candidate, Context, PlanOptions
from planning.placement.errors import InvalidProblem
from planning.placement.order import execution_order
from planning.placement.problem import Problem
from planning.placement.sorts import Sort, sorted_order

METHODS = ("auto", "exact", "bh", "sa", "ga", "psop-n", "psop-i", "psok-n", "psok-i")


@dataclass(frozen=True, slots=True)
class PlacedMug:
    """A planned spot: footprint corner in tray coordinates; ``order`` is the 1-based placing order;
    ``brim_mm`` the brim centre (tray coordinates) and ``handle_yaw_rad`` where the handle will point (tray
    frame, 0 = +x), None only in plans recorded before they were reported."""

    id: str
    type: str
    x_mm: int
    y_mm: int
    rotated: bool
    order: int
    brim_mm: tuple[float, float] | None = None
    handle_yaw_rad: float | None = None


@dataclass(frozen=True)
class PlanResult:
    """A plan: the spots in placing order, what stays on the counter, the placement parameters (n, A in mm²,
    E in J, t in s including the computation, s), the cost under the run's fitness and normalisation, and,
    when a solver proved it, whether n is the largest possible (``optimal``) and the bound on n."""

    method: str
    heuristic: str
    sort: str | None
    fitness: str
    cost_function: str
    seed: int
    wall_time_s: float
    placed: tuple[PlacedMug, ...]
    unplaced: tuple[str, ...]
    n: int
    A_mm2: float
    E_j: float
    t_s: float
    s: int
    cost: float
    optimal: bool | None = None
    upper_bound: int | None = None
    status: str = "feasible"
    evaluations: int = 0
    notes: tuple[str, ...] = ()

    def slots(self, problem: Problem) -> tuple[TraySlot, ...]:
        """The planned spots as the motion planner takes them (brim centre in the world frame, metres), in
        placing order."""
        out = []
        for p in self.placed:
            x, y = problem.to_world_mm(*problem.brim_centre_on_tray(p.type, p.x_mm, p.y_mm))
            out.append(TraySlot(p.id, p.type, x / 1000.0, y / 1000.0, p.rotated))
        return tuple(out)

    def to_json(self) -> dict[str, object]:
        return {
            "method": self.method,
            "heuristic": self.heuristic,
            "sort": self.sort,
            "fitness": self.fitness,
            "cost_function": self.cost_function,
            "seed": self.seed,
            "wall_time_s": round(self.wall_time_s, 6),
            "placed": [
                {
                    "id": p.id,
                    "type": p.type,
                    "x_mm": p.x_mm,
                    "y_mm": p.y_mm,
                    "rotated": p.rotated,
                    "order": p.order,
                    "brim_mm": None if p.brim_mm is None else [round(v, 3) for v in p.brim_mm],
                    "handle_yaw_rad": None if p.handle_yaw_rad is None else round(p.handle_yaw_rad, 6),
                }
                for p in self.placed
            ],
            "unplaced": list(self.unplaced),
            "n": self.n,
            "A": self.A_mm2,
            "E": round(self.E_j, 6),
            "t": round(self.t_s, 6),
            "s": self.s,
            "cost": round(self.cost, 6),
            "optimal": self.optimal,
            "upper_bound": self.upper_bound,
            "gap": None if self.upper_bound is None else self.upper_bound - self.n,
            "status": self.status,
            "evaluations": self.evaluations,
            "notes": list(self.notes),
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, object]) -> PlanResult:
        """The plan ``to_json`` wrote (a recording's ``plan`` message); ``ValueError`` naming the field that
        is missing or of the wrong type."""
        placed = []
        for i, item in enumerate(_field(doc, "placed", list)):
            if not isinstance(item, Mapping):
                raise ValueError(f"plan.placed.{i} is {item!r}, not an object")
            placed.append(
                PlacedMug(
                    _field(item, "id", str),
                    _field(item, "type", str),
                    _field(item, "x_mm", int),
                    _field(item, "y_mm", int),
                    _field(item, "rotated", bool),
                    _field(item, "order", int),
                    _brim(item, i),
                    None if item.get("handle_yaw_rad") is None else _field(item, "handle_yaw_rad", float),
                )
            )
        optimal = doc.get("optimal")
        bound = doc.get("upper_bound")
        return cls(
            method=_field(doc, "method", str),
            heuristic=_field(doc, "heuristic", str),
            sort=None if doc.get("sort") is None else _field(doc, "sort", str),
            fitness=_field(doc, "fitness", str),
            cost_function=_field(doc, "cost_function", str),
            seed=_field(doc, "seed", int),
            wall_time_s=_field(doc, "wall_time_s", float),
            placed=tuple(placed),
            unplaced=tuple(str(u) for u in _field(doc, "unplaced", list)),
            n=_field(doc, "n", int),
            A_mm2=_field(doc, "A", float),
            E_j=_field(doc, "E", float),
            t_s=_field(doc, "t_plan_s" if "t_plan_s" in doc else "t", float),
            s=_field(doc, "s", int),
            cost=_field(doc, "cost", float),
            optimal=optimal if isinstance(optimal, bool) else None,
            upper_bound=bound if isinstance(bound, int) and not isinstance(bound, bool) else None,
            status=str(doc.get("status", "feasible")),
            evaluations=_field(doc, "evaluations", int) if "evaluations" in doc else 0,
            notes=tuple(str(n) for n in _field(doc, "notes", list)) if "notes" in doc else (),
        )


F = TypeVar("F", str, int, float, bool, list)  # type: ignore[type-arg]


def _brim(item: Mapping[str, object], i: int) -> tuple[float, float] | None:
    value = item.get("brim_mm")
    if value is None:
        return None
    if (
        not isinstance(value, list)
        or len(value) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise ValueError(f"plan.placed.{i}.brim_mm is {value!r}, not [x, y]")
    return float(value[0]), float(value[1])


def _field(doc: Mapping[str, object], key: str, kind: type[F]) -> F:
    """``doc[key]`` as ``kind`` (an int will do for a float; a bool is never a number)."""
    value = doc.get(key)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)  # type: ignore[return-value]
    if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
        raise ValueError(f"plan.{key} is {value!r}, not {kind.__name__}")
    return value


_DEFAULT_OPTIONS = PlanOptions()


def plan(problem: Problem, options: PlanOptions = _DEFAULT_OPTIONS) -> PlanResult:
    """Plan where each counter mug goes on the tray and in which order, with the chosen method."""
    if options.method not in METHODS:
        raise InvalidProblem(f"method: unknown method {options.method!r} (known: {', '.join(METHODS)})")
    if not options.time_limit_s > 0:
        raise InvalidProblem(f"time_limit_s: must be positive, got {options.time_limit_s}")
    method = _method(options.method)  # imported before the clock starts: a one-off cost per process
    ctx = Context(problem, options)
    if problem.footprint_kind == "mug":  # the method gives the rectangle start (see ``mugshaped``)
        from planning.placement import mugshaped

        return _result(ctx, mugshaped.run(ctx, method))
    return _result(ctx, method(ctx))


def _method(name: str) -> Callable[[Context], Candidate]:
    """The method's entry point, imported on use: OR-Tools (``exact``, ``auto``) and the metaheuristics cost
    start-up time the other methods need not pay."""
    if name == "bh":
        return best_heuristic
    if name == "auto":
        from planning.placement import auto

        return auto.run
    if name == "exact":
        from planning.placement import exact

        return exact.run
    if name == "sa":
        from planning.placement import sa

        return sa.run
    if name == "ga":
        from planning.placement import ga

        return ga.run
    if name in ("psop-n", "psop-i"):
        from planning.placement import psop

        return psop.run_normal if name == "psop-n" else psop.run_improved
    from planning.placement import psok

    return psok.run_normal if name == "psok-n" else psok.run_improved


def best_heuristic(ctx: Context) -> Candidate:
    """BH (§5.3.2): each initial order packed once with the heuristic; the best under the fitness wins.

    With no ``sort`` given every deterministic sort (CIF, NIS, NDS by length and width) is tried."""
    sorts = [ctx.sort] if ctx.sort else [s for s in Sort if s is not Sort.RO]
    packer = ctx.packer()
    scored = []
    for s in sorts:
        packing = packer.pack(sorted_order(ctx.problem, s, ctx.rng))
        scored.append((packing, ctx.evaluate(packing)))
    best = scored[0]
    for item in scored[1:]:
        if ctx.fitness.better(item[1], best[1]):
            best = item
    return Candidate.of(best[0])


def _result(ctx: Context, c: Candidate) -> PlanResult:
    p = ctx.problem
    ev = ctx.evaluator
    metrics = ev.metrics_of_layout(c.layout)
    ctx.fitness.norm.observe(metrics)
    footprints = [(m, x, y, *p.footprint(p.mugs[m].type, r)) for m, x, y, r in c.layout]
    order = {m: k + 1 for k, m in enumerate(execution_order(footprints))}
    by_mug = {m: (x, y, r) for m, x, y, r in c.layout}
    placed = tuple(
        PlacedMug(
            p.mugs[m].id,
            p.mugs[m].type,
            by_mug[m][0],
            by_mug[m][1],
            by_mug[m][2],
            order[m],
            brim := p.brim_centre_on_tray(p.mugs[m].type, by_mug[m][0], by_mug[m][1]),
            _handle_yaw(p, m, brim, by_mug[m][2]),
        )
        for m in sorted(by_mug, key=order.__getitem__)
    )
    unplaced = tuple(mug.id for i, mug in enumerate(p.mugs) if i not in by_mug)
    o = ctx.options
    wall = ctx.elapsed()
    return PlanResult(
        method=o.method,
        heuristic=ctx.heuristic.value,
        sort=ctx.sort.value if ctx.sort else None,
        fitness=ctx.fitness.method.value,
        cost_function=ctx.fitness.cost.value,
        seed=o.seed,
        wall_time_s=wall,
        placed=placed,
        unplaced=unplaced,
        n=metrics.n,
        A_mm2=metrics.A,
        E_j=metrics.E,
        t_s=wall + metrics.t,
        s=metrics.s,
        cost=ctx.fitness.value(metrics),
        optimal=c.optimal,
        upper_bound=c.upper_bound,
        status=c.status,
        evaluations=ctx.evaluations,
        notes=c.notes,
    )


def _handle_yaw(problem: Problem, mug: int, brim: tuple[float, float], rotated: bool) -> float:
    """Where the arm will leave the handle (tray frame): the slot's bearing turned by the mug's handle angle
    (``shapes``); a rotated rectangle (which the arm cannot realise) as the rectangle model has it, +y."""
    if rotated:
        return math.pi / 2
    return problem.handle_yaw_on_tray(*brim, problem.relative_yaw(mug))
