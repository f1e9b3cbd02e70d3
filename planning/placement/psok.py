"""PSOk, the key-based particle swarm of §4.2.5.2 (Fig 4.13-4.16), normal and improved, §5.3 parameters.

Each mug is a particle with a key in [0, 1]; the configuration packs the mugs in key order with the
heuristic. Keys start as sorted random numbers handed out in the sort method's order (so the first packing
follows κ), velocities are drawn in ±``VELOCITY_LIMIT`` (Yarpiz's 10 % of the key range, [109]). Each of
the τ_max iterations packs, scores the configuration (its best so far is the answer) and each particle
(placed or not, its own area, energy and time, under a separate running normalisation), updates personal,
local and global bests, and moves every key by Eq 4.25-4.26, or with probability PS by the improved rule
Eq 4.27 that also pulls towards the second-best particle. Keys leaving [0, 1] are clamped and their velocity
mirrored.
"""

from __future__ import annotations

from dataclasses import dataclass

from description import thesis
from planning.placement.context import Candidate, Context
from planning.placement.cost import Fitness, Metrics
from planning.placement.packing import Packing
from planning.placement.sorts import Sort

VELOCITY_LIMIT = 0.1


@dataclass(frozen=True, slots=True)
class _Best:
    """A remembered particle: which mug, its key then, and its particle-level parameters then."""

    mug: int
    key: float
    metrics: Metrics


def run_normal(ctx: Context) -> Candidate:
    return _run(ctx, improved=False)


def run_improved(ctx: Context) -> Candidate:
    return _run(ctx, improved=True)


def _run(ctx: Context, *, improved: bool) -> Candidate:
    params = thesis.PSO_PARAMS
    rng = ctx.rng
    n_total = len(ctx.problem.mugs)
    if n_total == 0:
        return Candidate(())
    packer = ctx.packer()
    ev = ctx.evaluator
    order = ctx.initial_order()
    keys = [0.0] * n_total
    for mug, k in zip(order, sorted(rng.random() for _ in range(n_total)), strict=True):
        keys[mug] = k
    if (ctx.sort or Sort.NIS_L) is Sort.RO:
        order = sorted(range(n_total), key=keys.__getitem__)
    velocity = [rng.uniform(-VELOCITY_LIMIT, VELOCITY_LIMIT) for _ in range(n_total)]
    particle_fitness = Fitness(ctx.fitness.method, ctx.fitness.cost, ctx.fitness.weights, ctx.fitness.ranking)
    personal: list[_Best | None] = [None] * n_total
    global_best: _Best | None = None
    previous_global: _Best | None = None
    second_best: _Best | None = None
    best_config: tuple[Packing, Metrics] | None = None

    def better(a: _Best | None, b: _Best | None) -> bool:
        """IsCostDecreased for particles; an unset best (cost 1 in the thesis) loses to anything."""
        return a is not None and (b is None or particle_fitness.better(a.metrics, b.metrics))

    for tau in range(1, params.tau_max + 1):
        omega = params.w_max - (params.w_max - params.w_min) * tau / params.tau_max
        packing = packer.pack(order)
        config = ctx.evaluate(packing)
        spots = packing.spot_of()
        current: list[_Best] = []
        for mug in range(n_total):
            spot = spots.get(mug)
            if spot is None:
                m = Metrics(0, 0.0, 0.0, 0.0, config.s)
            else:
                dt, de = ev.move(mug, *spot)
                m = Metrics(1, ev.area(mug), de, dt, config.s)
            particle_fitness.norm.observe(m)
            current.append(_Best(mug, keys[mug], m))
        # NormalPSOk (Fig 4.15)
        local_best: _Best | None = None
        moved_global = False
        for mug in range(n_total):
            if better(current[mug], personal[mug]):
                personal[mug] = current[mug]
        for mug in range(n_total):
            if better(personal[mug], local_best):
                local_best = personal[mug]
        if better(local_best, global_best):
            previous_global, global_best, moved_global = global_best, local_best, True
        if best_config is None or ctx.fitness.better(config, best_config[1]):
            best_config = (packing, config)
        assert global_best is not None
        use_improved = improved and n_total >= 2
        if use_improved:
            # ImprovedPSOk (Fig 4.16): track the second-best particle.
            if moved_global:
                second_best = previous_global
                for mug in range(n_total):
                    if (
                        local_best is not None
                        and mug != local_best.mug
                        and better(personal[mug], second_best)
                    ):
                        second_best = personal[mug]
            elif better(local_best, second_best):
                second_best = local_best
            use_improved = rng.random() <= params.ps and second_best is not None
        for mug in range(n_total):
            own = personal[mug]
            assert own is not None
            v = (
                omega * velocity[mug]
                + params.c1 * rng.random() * (own.key - keys[mug])
                + params.c2 * rng.random() * (global_best.key - keys[mug])
            )
            if use_improved and second_best is not None:
                v += params.c3 * rng.random() * (second_best.key - keys[mug])
            k = keys[mug] + v
            if k < 0.0 or k > 1.0:
                k = min(max(k, 0.0), 1.0)
                v = -v
            keys[mug], velocity[mug] = k, v
        order = sorted(range(n_total), key=keys.__getitem__)
    assert best_config is not None
    return Candidate.of(best_config[0])
