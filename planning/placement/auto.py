"""``auto``: the best layout found within the budget, with the gap to the proven bound.

First every fill heuristic packs every deterministic sort order (a few milliseconds: a good layout at once,
and the fallback should the solver run out of time); then the exact CP-SAT model runs with most of the
budget, counted in CP-SAT's deterministic time, not on the wall clock. Should it not prove its count (large
instances with rotation), simulated annealing runs its schedule (§5.3's, a fixed number of steps). The
candidates are compared with the run's fitness; when the best one reaches the proven bound, the result says
it is optimal. Nothing here reads a clock, so a seed gives the same plan on a busy machine as on an idle one.
"""

from __future__ import annotations

from planning.placement import exact, sa
from planning.placement.context import Candidate, Context
from planning.placement.cost import Metrics
from planning.placement.heuristics import Heuristic
from planning.placement.sorts import Sort, sorted_order

# Kept back from the budget (for the heuristics and building the result, as when the budget was wall time).
_RESERVE_S = 0.02
# The exact model's share of the budget (deterministic time, both of its phases).
_EXACT_SHARE = 0.6


def run(ctx: Context) -> Candidate:
    best: tuple[Candidate, Metrics] | None = None

    def offer(c: Candidate) -> None:
        nonlocal best
        m = ctx.evaluator.metrics_of_layout(c.layout)
        ctx.fitness.norm.observe(m)
        ctx.evaluations += 1
        if best is None or ctx.fitness.better(m, best[1]):
            best = (c, m)

    sorts = [ctx.sort] if ctx.sort else [s for s in Sort if s is not Sort.RO]
    orders = [sorted_order(ctx.problem, s, ctx.rng) for s in sorts]
    for h in Heuristic:
        packer = ctx.packer(h)
        for order in orders:
            offer(Candidate.of(packer.pack(order)))
    budget = ctx.options.time_limit_s - _RESERVE_S
    notes: tuple[str, ...] = ()
    bound: int | None = None
    optimal: bool | None = None
    if budget > 0:
        outcome = exact.solve(
            ctx.problem,
            deterministic_limit=budget * _EXACT_SHARE,
            seed=ctx.options.seed,
            cache_dir=ctx.options.cache_dir,
        )
        bound = outcome.upper_bound
        if outcome.spots:
            offer(Candidate(exact.assign(ctx, outcome.spots)))
        optimal = outcome.optimal
        assert best is not None
        if not optimal and best[1].n < bound:
            offer(sa.run(ctx))
            notes = ("exact model unproven within the budget; simulated annealing ran its schedule",)
    else:
        notes = ("no budget left for the exact model; heuristics only",)
    assert best is not None
    chosen, metrics = best
    proven = optimal is True and bound is not None and metrics.n == bound
    return Candidate(
        chosen.layout,
        optimal=proven if bound is not None else None,
        upper_bound=bound,
        status="optimal" if proven else "feasible",
        notes=notes,
    )
