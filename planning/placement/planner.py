"""``plan()``: one entry point for every placement method; returns a layout, its cost and a placing order.

A pure computation: it logs nothing (the caller, e.g. the daemon's ``plan`` state, logs the outcome with its
own context) and so never writes to stdout, which ``dishbot plan --json`` reserves for the result."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from planning.placement.context import Candidate, Context, PlanOptions
from planning.placement.errors import InvalidProblem
from planning.placement.order import execution_order
from planning.placement.problem import Problem
from planning.placement.sorts import Sort, sorted_order
from validation import UNKNOWN_KEYS_IGNORED, Invalid, convert

if TYPE_CHECKING:
    from planning.interfaces import TraySlot

METHODS = ("auto", "exact", "bh", "sa", "ga", "psop-n", "psop-i", "psok-n", "psok-i")


@dataclass(frozen=True, slots=True)
class PlacedMug:
    """A planned spot: footprint corner in tray coordinates; ``order`` is the 1-based placing order;
    ``brim_mm`` the brim centre (tray coordinates) and ``handle_yaw_rad`` where the handle will point (tray
    frame, 0 = +x), None only in plans recorded before they were reported. As a recorded plan's ``placed``
    entry it is read by ``PlanResult.from_json``, passing over keys it does not declare."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
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
        from planning.interfaces import TraySlot  # only the motion planner's callers need it

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
    def from_json(cls, doc: object) -> PlanResult:
        """The plan ``to_json`` wrote (a recording's ``plan`` message), checked by the one validator against
        its declared shape (``_PlanMessage``); ``ValueError`` (``validation.Invalid``), one line naming the
        field that is missing or of the wrong type, otherwise."""
        m = convert(doc, _PlanMessage, name="plan")
        return cls(
            method=m.method,
            heuristic=m.heuristic,
            sort=m.sort,
            fitness=m.fitness,
            cost_function=m.cost_function,
            seed=m.seed,
            wall_time_s=m.wall_time_s,
            placed=m.placed,
            unplaced=m.unplaced,
            n=m.n,
            A_mm2=m.A,
            E_j=m.E,
            t_s=m.t_plan_s if m.t_plan_s is not None else m.t or 0.0,  # one of them is set
            s=m.s,
            cost=m.cost,
            optimal=m.optimal,
            upper_bound=m.upper_bound,
            status=m.status,
            evaluations=m.evaluations,
            notes=m.notes,
        )


# --- a recorded plan's shape: what ``PlanResult.to_json`` writes, and the plan message adds -------------
# Its own names for three of the result's fields (``A``, ``E``, and ``t`` or ``t_plan_s``), so it is a
# shape of its own. Keys it does not declare are passed over: the published message adds its own
# (``slots``, ``out_of_reach``, ``gap``), and a later version may add more.


@dataclass(frozen=True, slots=True)
class _PlanMessage:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    method: str
    heuristic: str
    fitness: str
    cost_function: str
    seed: int
    wall_time_s: float
    placed: tuple[PlacedMug, ...]
    unplaced: tuple[str, ...]
    n: int
    A: float
    E: float
    s: int
    cost: float
    sort: str | None = None
    # The plan's time estimate: ``t`` as ``to_json`` writes it, ``t_plan_s`` in the published message
    # (whose ``t`` is the time of publication).
    t: float | None = None
    t_plan_s: float | None = None
    optimal: bool | None = None
    upper_bound: int | None = None
    status: str = "feasible"
    evaluations: int = 0
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.t is None and self.t_plan_s is None:
            raise Invalid("t: missing")


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
