"""Planning with mug-shaped footprints (``Problem.footprint_kind == "mug"``).

1. The chosen rectangle method runs on the same problem with rectangle footprints (``auto``: the proven
   rectangle optimum). Its layout, each mug's handle turned to the yaw the arm will give it, is checked as
   mug outlines; it is the start, so the result never holds fewer mugs than it, except where the arm
   would turn a handle out of its rectangle: such a mug is dropped from the start (said in the notes; on
   datasets 4 and 5 one small mug in a near corner of the full-size tray, and the packer beats the start
   by six mugs there).
2. The mug packer (``mugpack``) fills the tray with outlines: the class sequences largest first and
   smallest first under every scan, then seeded shuffles under the scans that packed the most (and the
   slanted rows from the arm's side), up to a fixed number of packings, so a seed repeats a run exactly;
   ``SAFETY_FACTOR`` times the time limit in CPU time of the planning thread (not wall time, so other jobs
   on the machine do not change the result) stops it early on a slow machine (said in the notes).
3. Each packing's spots go to counter mugs of their class with the least move energy (Hungarian method),
   and the layouts are compared: more mugs first, then the run's fitness (the thesis's costs).

The upper bound is the area bound: no more mugs than the smallest outlines, grown by half the clearance,
whose areas fit in the tray's free area.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from perception.assignment import least_cost_assignment
from planning.placement.context import Candidate, Context, Layout
from planning.placement.cost import Metrics
from planning.placement.errors import InvalidProblem
from planning.placement.mugpack import SCANS, MugPacker, Scan, Spot, fixed_bodies
from planning.placement.problem import Problem
from planning.placement.shapes import Bodies, MugOutline, keeps_clear

# The search packs at most this many layouts, plus this many per counter mug (154 for 12 mugs, 190 for 30):
# about 1.7 s of CPU on the robot tray and 6 s on the full-size one (issue 24: 2 s and 10 s).
PACKS_BASE = 130
PACKS_PER_MUG = 2
# Seeded shuffles are packed under this many scans: those whose sorted sequences packed the most mugs, then
# the slanted row scans from the arm's side (which found the fullest robot trays) up to ``SHUFFLE_SCANS``.
TOP_SCANS = 4
SHUFFLE_SCANS = 8
# The search stops after this many times ``time_limit_s`` of its thread's CPU time, whatever is left.
SAFETY_FACTOR = 8.0


def run(ctx: Context, rect_method: Callable[[Context], Candidate]) -> Candidate:
    problem = ctx.problem
    notes: list[str] = []
    best: tuple[Layout, Metrics] | None = None

    def offer(layout: Layout) -> None:
        nonlocal best
        m = ctx.evaluator.metrics_of_layout(layout)
        ctx.fitness.norm.observe(m)
        ctx.evaluations += 1
        if best is None or m.n > best[1].n or (m.n == best[1].n and ctx.fitness.better(m, best[1])):
            best = (layout, m)

    start = _rectangle_start(ctx, rect_method, notes)
    offer(start)
    rect_n = len(start)
    bound = area_bound(problem)
    packer = MugPacker(problem, cache_dir=ctx.options.cache_dir)
    now = time.thread_time  # CPU time of this thread: other jobs on the machine do not change the result
    deadline = now() + SAFETY_FACTOR * ctx.options.time_limit_s
    budget = PACKS_BASE + PACKS_PER_MUG * len(problem.mugs)
    packed = 0
    by_scan: dict[Scan, int] = {}
    stopped = False

    def pack(sequence: list[int], scan: Scan) -> bool:
        """Packs one layout and offers it; False once the budget or the time is spent."""
        nonlocal packed, stopped
        assert best is not None
        if packed >= budget or best[1].n >= bound:  # nothing can place more than the bound
            return False
        if now() > deadline:
            stopped = True
            return False
        spots = packer.pack(sequence, scan)
        packed += 1
        by_scan[scan] = max(by_scan.get(scan, 0), len(spots))
        if len(spots) >= best[1].n:
            offer(_assigned(ctx, packer, spots))
        return True

    large_first = _large_first(packer, ctx.problem)
    going = all(pack(sequence, scan) for sequence in (large_first, large_first[::-1]) for scan in SCANS)
    top = sorted(by_scan, key=lambda scan: -by_scan[scan])[:TOP_SCANS]  # stable: SCANS' order breaks ties
    rows = [scan for scan in SCANS if scan[0] == 0 and scan[1] != 0 and scan not in top]
    top += rows[: SHUFFLE_SCANS - len(top)]
    while going and large_first:
        shuffled = list(large_first)
        ctx.rng.shuffle(shuffled)
        going = all(pack(shuffled, scan) for scan in top)
    if stopped:
        notes.append(f"mug packing stopped at the time limit after {packed} packings")
    assert best is not None
    layout, metrics = best
    notes.insert(0, f"mug-shaped: {rect_n} from the rectangle layout, {metrics.n} after {packed} packings")
    return Candidate(
        layout,
        optimal=metrics.n == bound,
        upper_bound=bound,
        status="optimal" if metrics.n == bound else "feasible",
        notes=tuple(notes),
    )


def _rectangle_start(ctx: Context, method: Callable[[Context], Candidate], notes: list[str]) -> Layout:
    """The rectangle method's layout, less any mug whose outline (handle turned as the arm turns it) would
    leave the tray or come too close to another."""
    try:
        rect_problem = replace(ctx.problem, footprint_kind="rect")
    except InvalidProblem as e:  # mugs on the tray nested closer than their rectangles
        notes.append(f"no rectangle start: {e}")
        return ()
    layout = method(Context(rect_problem, ctx.options)).layout
    kept = valid_subset(ctx.problem, layout)
    if len(kept) < len(layout):
        notes.append(
            f"{len(layout) - len(kept)} mugs of the rectangle layout dropped: their handles would turn"
        )
    return kept


def valid_subset(problem: Problem, layout: Layout) -> Layout:
    """The mugs of ``layout``, in order, that fit as outlines beside those kept before them."""
    fixed = fixed_bodies(problem)
    kept: list[tuple[int, int, int, bool]] = []
    bodies: list[Bodies] = []
    for entry in layout:
        mug, x, y, rotated = entry
        if rotated:
            continue
        b = mug_body(problem, mug, x, y)
        if not keeps_clear(b.wall_gap(problem.tray_size_mm), problem.tolerance_mm / 2.0)[0]:
            continue
        others = [fixed, *bodies]
        if all(
            keeps_clear(b.gap_to(o, k), float(problem.tolerance_mm))[0]
            for o in others
            for k in range(len(o.cx))
        ):
            kept.append(entry)
            bodies.append(b)
    return tuple(kept)


def mug_body(problem: Problem, mug: int, x: float, y: float) -> Bodies:
    """Counter mug ``mug`` placed with its footprint corner at (x, y), its handle as the arm turns it."""
    m = problem.mugs[mug]
    bx, by = problem.brim_centre_on_tray(m.type, x, y)
    yaw = problem.handle_yaw_on_tray(bx, by, problem.relative_yaw(mug))
    return Bodies.build(
        MugOutline.of(problem.mug_types[m.type]), np.array([bx]), np.array([by]), np.array([yaw])
    )


def area_bound(problem: Problem) -> int:
    """How many counter mugs the tray's free area could hold at most: outlines grown by half the clearance
    (the area each mug keeps to itself), smallest first."""
    half = problem.tolerance_mm / 2.0
    free = float(problem.tray_size_mm[0] * problem.tray_size_mm[1])
    free -= sum(MugOutline.of(problem.mug_types[q.type]).area(half) for q in problem.placed)
    areas = sorted(MugOutline.of(problem.mug_types[m.type]).area(half) for m in problem.mugs)
    n = 0
    for a in areas:
        if a > free + 1e-6:
            break
        free -= a
        n += 1
    return n


def _large_first(packer: MugPacker, problem: Problem) -> list[int]:
    """The counter mugs' classes, largest outline first (then by class)."""
    size = {k: MugOutline.of(problem.mug_types[c.type]).area() for k, c in enumerate(packer.classes)}
    return sorted(packer.class_of, key=lambda k: (-size[k], k))


def _assigned(ctx: Context, packer: MugPacker, spots: Sequence[Spot]) -> Layout:
    """Counter mugs matched to the spots of their class with the least move energy (then time)."""
    by_class: dict[int, list[tuple[int, int]]] = defaultdict(list)
    for k, x, y in spots:
        by_class[k].append((x, y))
    layout: list[tuple[int, int, int, bool]] = []
    ev = ctx.evaluator
    for k, places in sorted(by_class.items()):
        mugs = [i for i, c in enumerate(packer.class_of) if c == k]
        cost = [[j + 1e-6 * s for s, j in (ev.move(i, x, y, False) for x, y in places)] for i in mugs]
        layout += [(mugs[r], *places[c], False) for r, c in least_cost_assignment(cost)]
    return tuple(layout)
