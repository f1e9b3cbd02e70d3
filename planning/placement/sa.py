"""Simulated annealing as §4.2.3 (Fig 4.6, 4.7) with the §5.3 parameters (T 1000, cooling 0.99, stop 0.01).

A configuration is a packing order. A neighbour swaps two mugs of different sizes in the configuration's
order (placed mugs first, in packing order, then the rest), repacks with the heuristic, then offers the
smallest unplaced mug right after the placed ones, repeatedly, while that places one more. The "energy" is the
fitness value (weighted sum, or the mean ranked cost parameter for ranking fitness). The run stops when the
temperature drops below T_abs or every mug is placed; the layout with the most mugs is kept if the best-cost
one has fewer.
"""

from __future__ import annotations

import math

from description import thesis
from planning.placement.context import Candidate, Context
from planning.placement.packing import Packer, Packing


def run(ctx: Context) -> Candidate:
    params = thesis.SA_PARAMS
    packer = ctx.packer()
    fitness = ctx.fitness
    n_total = len(ctx.problem.mugs)
    current = packer.pack(ctx.initial_order())
    m_current = ctx.evaluate(current)
    best, m_best = current, m_current
    most, m_most = current, m_current
    temperature = params.t_max
    while temperature > params.t_abs and n_total:
        new = _neighbour(ctx, packer, current)
        m_new = ctx.evaluate(new)
        e_new, e_current = fitness.value(m_new), fitness.value(m_current)
        if e_new <= e_current:
            current, m_current = new, m_new
            if e_new <= fitness.value(m_best):
                best, m_best = new, m_new
        elif math.exp(-(e_new - e_current) / temperature) > ctx.rng.random():
            current, m_current = new, m_new
        if m_new.n > m_most.n or (m_new.n == m_most.n and fitness.better(m_new, m_most)):
            most, m_most = new, m_new
        if m_current.n == n_total:
            break
        temperature *= params.cooling_rate
    return Candidate.of(most if m_best.n < m_most.n else best)


def configuration_order(packing: Packing) -> list[int]:
    """GetPlaceOrderOfConfiguration: placed mugs in packing order, then the unplaced ones."""
    return [*packing.placed, *packing.unplaced]


def _neighbour(ctx: Context, packer: Packer, s_in: Packing) -> Packing:
    order = configuration_order(s_in)
    n_total = len(order)
    codes = [packer.shape_code(m) for m in order]
    if len(set(codes)) < 2:
        return s_in  # every mug the same size: no swap changes anything
    rng = ctx.rng
    i = rng.randrange(n_total)
    j = rng.randrange(n_total)
    while j == i or codes[i] == codes[j]:
        j = rng.randrange(n_total)
    order[i], order[j] = order[j], order[i]
    s_cur = packer.pack(order)
    area = ctx.evaluator.area
    while s_cur.n < n_total:
        smallest = min(s_cur.unplaced, key=lambda m: (area(m), order.index(m)))
        trial = list(order)
        trial.remove(smallest)
        trial.insert(s_cur.n, smallest)
        s_new = packer.pack(trial)
        if s_new.n <= s_cur.n:
            break
        order, s_cur = trial, s_new
    return s_cur
