"""The genetic algorithm of §4.2.4 (Fig 4.8) with the §5.3 parameters (npop 50, ngen 30, nrep 10, PC 0.67,
PM 0.33).

A chromosome is an order of every mug (a virtual container holding all of them). The first individual
follows the sort method, the rest are random permutations; no duplicate chromosomes are admitted. Each
generation keeps the nrep best, then breeds until the population is full: with probability PC a partially
mapped crossover (PMX) of the best individual with a random one, else an inversion mutation (two genes swap
places) of the best. An
offspring is packed with the heuristic, its chromosome reordered (placed mugs first, in packing order), and
admitted if still not a duplicate; the population is re-sorted by fitness under the current normalisation.
The search stops early once every mug is placed.
"""

from __future__ import annotations

import random

from description import thesis
from planning.placement.context import Candidate, Context
from planning.placement.cost import Metrics
from planning.placement.packing import Packing

# Breeding gives up on a generation after this many duplicate offspring in a row; only reached when almost
# every permutation is already in the population (a handful of mugs), where the search is exhausted anyway.
_MAX_DUPLICATES_IN_A_ROW = 1000

Individual = tuple[tuple[int, ...], Packing, Metrics]


def run(ctx: Context) -> Candidate:
    params = thesis.GA_PARAMS
    packer = ctx.packer()
    n_total = len(ctx.problem.mugs)
    key = ctx.fitness.key

    def make(order: list[int]) -> Individual:
        packing = packer.pack(order)
        chromosome = (*packing.placed, *packing.unplaced)
        return chromosome, packing, ctx.evaluate(packing)

    population: list[Individual] = []
    seen: set[tuple[int, ...]] = set()

    def admit(order: list[int]) -> Individual | None:
        if tuple(order) in seen:
            return None
        ind = make(order)
        if ind[0] in seen:
            return None
        seen.add(tuple(order))
        seen.add(ind[0])
        population.append(ind)
        population.sort(key=lambda i: key(i[2]))
        return ind

    first = admit(ctx.initial_order())
    if first is None or n_total == 0 or first[2].n == n_total:
        return Candidate.of(population[0][1])
    rng = ctx.rng
    duplicates = 0
    while len(population) < params.npop and duplicates < _MAX_DUPLICATES_IN_A_ROW:
        order = list(range(n_total))
        rng.shuffle(order)
        ind = admit(order)
        duplicates = duplicates + 1 if ind is None else 0
        if ind is not None and ind[2].n == n_total:
            return Candidate.of(ind[1])
    for _ in range(params.ngen):
        previous = population
        population = previous[: params.nrep]
        seen = {i[0] for i in population}
        duplicates = 0
        while len(population) < params.npop and duplicates < _MAX_DUPLICATES_IN_A_ROW:
            best = population[0][0]
            if rng.choices((True, False), weights=(params.pc, params.pm))[0] and len(population) > 1:
                other = population[rng.randint(1, len(population) - 1)][0]
                child = pmx(best, other, rng)
            else:
                child = inversion(best, rng)
            ind = admit(child)
            duplicates = duplicates + 1 if ind is None else 0
            if ind is not None and ind[2].n == n_total:
                return Candidate.of(ind[1])
    return Candidate.of(population[0][1])


def pmx(p1: tuple[int, ...], p2: tuple[int, ...], rng: random.Random) -> list[int]:
    """Partially mapped crossover: the child keeps a slice of ``p1``; the rest comes from ``p2``, with genes
    that clash with the slice mapped through it."""
    n = len(p1)
    a, b = sorted(rng.sample(range(n + 1), 2))
    child: list[int | None] = [None] * n
    child[a:b] = p1[a:b]
    in_slice = set(p1[a:b])
    position_in_p2 = {g: i for i, g in enumerate(p2)}
    for i in range(a, b):
        gene = p2[i]
        if gene in in_slice:
            continue
        k = i
        while a <= k < b:
            k = position_in_p2[p1[k]]
        child[k] = gene
    return [g if g is not None else p2[i] for i, g in enumerate(child)]


def inversion(p: tuple[int, ...], rng: random.Random) -> list[int]:
    """The mutation of §4.2.4: two genes swap positions."""
    child = list(p)
    if len(child) > 1:
        i, j = rng.sample(range(len(child)), 2)
        child[i], child[j] = child[j], child[i]
    return child
