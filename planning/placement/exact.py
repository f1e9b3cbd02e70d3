"""``exact``: the largest number of mugs that fit, proven with OR-Tools CP-SAT, then the largest covered area.

Any packing can be pushed left and down until every footprint touches the tray edge, a mug already on the
tray, or another footprint on both its low sides; its corners then lie on "normal patterns": an edge (0 or a
fixed mug's far edge) plus a sum of footprint extents (Herz 1972; Christofides and Whitlock 1977). So a model
that chooses footprints on normal-pattern corners loses no packing. Two chosen footprints overlap exactly when
both cover the corner point (max x, max y) of their overlap, which is itself a normal-pattern point, so one
"at most one footprint covers this point" constraint per point makes the set-packing model exact.

Phase 1 maximises the number of mugs (and proves it); phase 2 keeps that number and maximises the covered
area (the ranking fitness's next criterion). Which counter mug takes which chosen spot is then an assignment
problem per mug type, solved exactly for the move energy (then time), for the layout and its mirror images
(which keep count and area). The energy is thus not minimised over every layout of that count and area: a
CP-SAT model of that found nothing better than this within a second. Every solve is single-threaded and
seeded and stops on a deterministic-time limit (CP-SAT's measure of work done, never the wall clock), so a
run repeats for a seed whatever else the machine is doing, even when a limit cuts a solve short.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from perception.assignment import least_cost_assignment
from planning.placement import cache
from planning.placement.context import Candidate, Context, Layout
from planning.placement.order import execution_order
from planning.placement.problem import Problem

if TYPE_CHECKING:
    from planning.placement.cpsat import Var

# Beyond this many (choice, covered point) pairs the set-packing model takes longer to build than to solve.
_MAX_POINT_MODEL_SIZE = 100_000


@dataclass(frozen=True, slots=True)
class _Shape:
    type: str
    rotated: bool
    fx: int
    fy: int


@dataclass(frozen=True)
class ExactOutcome:
    """The chosen spots [(type, x, y, rotated)], whether n is proven largest, and the proven bound on n."""

    spots: tuple[tuple[str, int, int, bool], ...]
    optimal: bool
    upper_bound: int
    status: str


def run(ctx: Context) -> Candidate:
    outcome = solve(
        ctx.problem,
        deterministic_limit=ctx.options.time_limit_s,
        seed=ctx.options.seed,
        cache_dir=ctx.options.cache_dir,
    )
    return Candidate(
        assign(ctx, outcome.spots),
        optimal=outcome.optimal,
        upper_bound=outcome.upper_bound,
        status=outcome.status,
    )


def normal_patterns(edges: Iterable[int], extents: Iterable[int], limit: int) -> list[int]:
    """Every edge + (non-negative integer combination of extents) that is at most ``limit``."""
    reach = [False] * (limit + 1)
    for e in edges:
        if 0 <= e <= limit:
            reach[e] = True
    sizes = sorted(set(extents))
    for v in range(limit + 1):
        if reach[v]:
            for s in sizes:
                if v + s <= limit:
                    reach[v + s] = True
    return [v for v in range(limit + 1) if reach[v]]


def solve(
    problem: Problem, *, deterministic_limit: float, seed: int = 0, cache_dir: Path | None = None
) -> ExactOutcome:
    """Place as many counter mugs as possible around the mugs already on the tray; see the module doc.
    ``deterministic_limit``: CP-SAT's deterministic time for both phases together (about seconds of solving
    on a typical machine; the same work, so the same result, on a slow or busy one). ``cache_dir``: where
    proven outcomes are kept between runs (``cache``; None: solve every time). OR-Tools is imported only
    when the model is solved."""
    tx, ty = problem.tray_size_mm
    counts: dict[str, int] = defaultdict(int)
    for m in problem.mugs:
        counts[m.type] += 1
    rotations = (False, True) if problem.allow_rotation else (False,)
    shapes = [
        _Shape(t, r, *problem.footprint(t, r))
        for t in sorted(counts)
        for r in rotations
        if problem.footprint(t, r)[0] <= tx and problem.footprint(t, r)[1] <= ty
    ]
    if not shapes:
        return ExactOutcome((), True, 0, "optimal")
    fixed = problem.obstacle_rects()
    # everything the outcome depends on: the key of a kept outcome
    question = {
        "tray": [tx, ty],
        "counts": sorted(counts.items()),
        "footprints": [[t, r, *problem.footprint(t, r)] for t in sorted(counts) for r in (False, True)],
        "rotation": problem.allow_rotation,
        "fixed": [list(f) for f in fixed],
        "placed": [[q.type, q.rotated] for q in problem.placed],
        "limit": deterministic_limit,
        "seed": seed,
    }
    digest = None
    if cache_dir is not None:
        build = cache.ortools_build()
        digest = None if build is None else cache.key(question, ("exact.py", "cpsat.py"), build)
    if cache_dir is not None and digest is not None:
        kept = _kept_outcome(cache.load_json(cache_dir, digest))
        if kept is not None:
            return kept
    xs = normal_patterns([0, *(x + fx for x, _, fx, _ in fixed)], [s.fx for s in shapes], tx)
    ys = normal_patterns([0, *(y + fy for _, y, _, fy in fixed)], [s.fy for s in shapes], ty)

    if _point_model_size(shapes, xs, ys, tx, ty) <= _MAX_POINT_MODEL_SIZE:
        outcome = _solve_points(problem, shapes, counts, fixed, xs, ys, limit=deterministic_limit, seed=seed)
    else:
        outcome = _solve_boxes(problem, shapes, counts, fixed, xs, ys, limit=deterministic_limit, seed=seed)
    if cache_dir is not None and digest is not None and outcome.optimal:
        answer: dict[str, object] = {
            "spots": [list(s) for s in outcome.spots],
            "optimal": outcome.optimal,
            "upper_bound": outcome.upper_bound,
            "status": outcome.status,
        }
        cache.store_json(cache_dir, digest, answer)
    return outcome


def _kept_outcome(doc: dict[str, object] | None) -> ExactOutcome | None:
    """The outcome ``cache.store_json`` kept, if it has the shape it was written with."""
    if doc is None:
        return None
    spots, bound, status = doc.get("spots"), doc.get("upper_bound"), doc.get("status")
    if not (isinstance(spots, list) and type(bound) is int and status == "optimal"):
        return None
    if doc.get("optimal") is not True:
        return None
    out: list[tuple[str, int, int, bool]] = []
    for s in spots:
        if not (
            isinstance(s, list)
            and len(s) == 4
            and isinstance(s[0], str)
            and type(s[1]) is int
            and type(s[2]) is int
            and type(s[3]) is bool
        ):
            return None
        out.append((s[0], s[1], s[2], s[3]))
    return ExactOutcome(tuple(out), True, bound, "optimal")


def _point_model_size(shapes: list[_Shape], xs: list[int], ys: list[int], tx: int, ty: int) -> int:
    """How many (choice, covered point) pairs the set-packing model would hold."""
    ax, ay = np.array(xs), np.array(ys)
    total = 0
    for s in shapes:
        cx, cy = ax[ax + s.fx <= tx], ay[ay + s.fy <= ty]
        per_x = np.searchsorted(ax, cx + s.fx) - np.searchsorted(ax, cx)
        per_y = np.searchsorted(ay, cy + s.fy) - np.searchsorted(ay, cy)
        total += int(per_x.sum()) * int(per_y.sum())
    return total


def _solve_points(
    problem: Problem,
    shapes: list[_Shape],
    counts: dict[str, int],
    fixed: list[tuple[int, int, int, int]],
    xs: list[int],
    ys: list[int],
    *,
    limit: float,
    seed: int,
) -> ExactOutcome:
    """The set-packing model over normal-pattern corners (see the module doc)."""
    from planning.placement import cpsat  # OR-Tools: only when a model is solved

    tx, ty = problem.tray_size_mm
    model = cpsat.Model()
    choices: list[tuple[_Shape, int, int, Var]] = []
    for s in shapes:
        for x in xs:
            if x + s.fx > tx:
                break
            for y in ys:
                if y + s.fy > ty:
                    break
                if any(_overlap((x, y, s.fx, s.fy), f) for f in fixed):
                    continue
                choices.append((s, x, y, model.bool_var(f"{s.type}{'r' if s.rotated else ''}_{x}_{y}")))
    covering: dict[tuple[int, int], list[Var]] = defaultdict(list)
    x_index = np.array(xs)
    y_index = np.array(ys)
    for s, x, y, var in choices:
        for px in x_index[(x_index >= x) & (x_index < x + s.fx)]:
            for py in y_index[(y_index >= y) & (y_index < y + s.fy)]:
                covering[(int(px), int(py))].append(var)
    for group in covering.values():
        if len(group) > 1:
            model.at_most_one(group)
    for t, c in counts.items():
        of_type = [(1, v) for s, _, _, v in choices if s.type == t]
        if of_type:
            model.at_most(of_type, c)
    every = [(1, v) for *_, v in choices]
    model.maximize(every)

    solution = cpsat.solve(model, deterministic_limit=limit, seed=seed)
    if not solution.found:
        return ExactOutcome((), False, _area_bound(problem, counts), "unknown")
    n_best = round(solution.objective)
    proven = solution.status == "OPTIMAL"
    bound = n_best if proven else min(math.floor(solution.bound + 1e-6), _area_bound(problem, counts))
    chosen = [(s, x, y) for s, x, y, v in choices if solution.value(v)]

    # Phase 2: the same number of mugs, as much covered area as possible (bigger mugs first).
    remaining = limit - solution.deterministic_time
    if proven and remaining > 0.01:
        model.equal(every, n_best)
        model.maximize([(s.fx * s.fy, v) for s, _, _, v in choices])
        for s, x, y, v in choices:
            model.hint(v, (s, x, y) in chosen)
        second = cpsat.solve(model, deterministic_limit=remaining, seed=seed)
        if second.found:
            chosen = [(s, x, y) for s, x, y, v in choices if second.value(v)]
    spots = tuple((s.type, x, y, s.rotated) for s, x, y in chosen)
    return ExactOutcome(spots, proven, bound, "optimal" if proven else "feasible")


def _solve_boxes(
    problem: Problem,
    shapes: list[_Shape],
    counts: dict[str, int],
    fixed: list[tuple[int, int, int, int]],
    xs: list[int],
    ys: list[int],
    *,
    limit: float,
    seed: int,
) -> ExactOutcome:
    """For instances whose point model is too big (rotation multiplies the normal patterns): one optional box
    per counter mug and orientation under CP-SAT's 2D no-overlap, corners restricted to normal patterns."""
    from planning.placement import cpsat  # OR-Tools: only when a model is solved

    tx, ty = problem.tray_size_mm
    model = cpsat.Model()
    x_boxes, y_boxes = [], []
    for x, y, fx, fy in fixed:
        x_boxes.append(model.fixed_interval(x, fx, "fixed_x"))
        y_boxes.append(model.fixed_interval(y, fy, "fixed_y"))
    placed_terms = []
    slots: list[tuple[_Shape, Var, Var, Var]] = []
    for t in sorted(counts):
        previous: Var | None = None
        for k in range(counts[t]):
            present = model.bool_var(f"{t}{k}")
            options = []
            for s in (s for s in shapes if s.type == t):
                lit = model.bool_var(f"{t}{k}_{'r' if s.rotated else 'u'}")
                x_var = model.int_var([v for v in xs if v + s.fx <= tx], f"x_{t}{k}{s.rotated}")
                y_var = model.int_var([v for v in ys if v + s.fy <= ty], f"y_{t}{k}{s.rotated}")
                x_boxes.append(model.optional_interval(x_var, s.fx, lit, "bx"))
                y_boxes.append(model.optional_interval(y_var, s.fy, lit, "by"))
                options.append(lit)
                slots.append((s, x_var, y_var, lit))
            model.equal([(1, o) for o in options] + [(-1, present)], 0)
            if previous is not None:
                model.implication(present, previous)  # identical mugs: fill slots in order
            previous = present
            placed_terms.append((1, present))
    model.no_overlap_2d(x_boxes, y_boxes)
    model.maximize(placed_terms)
    solution = cpsat.solve(model, deterministic_limit=limit, seed=seed)
    area_bound = _area_bound(problem, counts)
    if not solution.found:
        return ExactOutcome((), False, area_bound, "unknown")
    proven = solution.status == "OPTIMAL"
    n_best = round(solution.objective)
    bound = n_best if proven else min(math.floor(solution.bound + 1e-6), area_bound)
    spots = tuple(
        (s.type, solution.value(x), solution.value(y), s.rotated)
        for s, x, y, lit in slots
        if solution.value(lit)
    )
    return ExactOutcome(spots, proven, bound, "optimal" if proven else "feasible")


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]


def _area_bound(problem: Problem, counts: dict[str, int]) -> int:
    """How many mugs the free tray area could hold at most, smallest footprints first."""
    free = problem.tray_size_mm[0] * problem.tray_size_mm[1]
    free -= sum(math.prod(problem.footprint(q.type, q.rotated)) for q in problem.placed)
    n = 0
    for t in sorted(counts, key=lambda t: math.prod(problem.footprint(t))):
        a = math.prod(problem.footprint(t))
        take = min(counts[t], max(free, 0) // a)
        n += take
        free -= take * a
    return n


def assign(ctx: Context, spots: Iterable[tuple[str, int, int, bool]]) -> Layout:
    """Which counter mug goes to which spot, and which mirror image of the layout to use.

    Mirroring the layout along the tray's x or y axis keeps the count and the area, so among the (up to)
    four images that stay clear of mugs already on the tray, and for each the per-type assignment with the
    least move energy (then time, Hungarian method), the one with the least energy wins. The layout comes in
    placing order, so its sortedness is that of the order the arm follows."""
    p = ctx.problem
    tx, ty = p.tray_size_mm
    fixed = p.obstacle_rects()
    spots = list(spots)
    best: tuple[float, list[tuple[int, int, int, bool]]] | None = None
    for flip_x in (False, True):
        for flip_y in (False, True):
            image = []
            for t, x, y, r in spots:
                fx, fy = p.footprint(t, r)
                image.append((t, tx - x - fx if flip_x else x, ty - y - fy if flip_y else y, r))
            if any(_overlap((x, y, *p.footprint(t, r)), f) for t, x, y, r in image for f in fixed):
                continue
            energy, layout = _least_energy_assignment(ctx, image)
            if best is None or energy < best[0] - 1e-9:
                best = (energy, layout)
    assert best is not None  # the unmirrored layout never overlaps the fixed mugs
    by_mug = {e[0]: e for e in best[1]}
    order = execution_order([(m, x, y, *p.footprint(p.mugs[m].type, r)) for m, x, y, r in best[1]])
    return tuple(by_mug[m] for m in order)


def _least_energy_assignment(
    ctx: Context, spots: list[tuple[str, int, int, bool]]
) -> tuple[float, list[tuple[int, int, int, bool]]]:
    """Per mug type, the counter mugs matched to the spots with the least move energy (then time)."""
    by_type: dict[str, list[tuple[int, int, bool]]] = defaultdict(list)
    for t, x, y, r in spots:
        by_type[t].append((x, y, r))
    layout = []
    total = 0.0
    ev = ctx.evaluator
    for t, places in sorted(by_type.items()):
        mugs = [i for i, m in enumerate(ctx.problem.mugs) if m.type == t]
        cost = [[j + 1e-6 * s for s, j in (ev.move(i, *pl) for pl in places)] for i in mugs]
        pairs = least_cost_assignment(cost)
        total += sum(cost[r][c] for r, c in pairs)
        layout += [(mugs[r], *places[c]) for r, c in pairs]
    return total, layout
