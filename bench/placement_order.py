"""``dishbot bench placement --layouts N``: the placing order checked with the arm (issue 24, item 3) on N
random counter layouts per dataset.

Each layout puts the dataset's mugs at random on its counter (seeded: the same seed gives the same layouts;
brims at least 20 mm apart, no handle within 10 mm of another mug's brim, handles pointing away from the
arm as the simulated counters set them), in the kinematic cell with the dataset's tray. The mug-shaped plan
is made twice: checked with the arm (``planning.placement.checked.plan_with_arm``) and unchecked (the
packer's layout in its far-edge-first order). Each is then run as the job runs it: slot by slot in the
plan's order, ``plan_for_slot`` with the counter as it then stands and the mugs placed so far (a blocked
slot's mug may be swapped for another of its type, as the job does). An order-induced collision is a slot
refused because the gripper or the held mug would hit a mug on the tray or on the counter (the swept
check's refusal names the mug it would hit); other refusals (out of reach, joint limits, walls) are
counted apart.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import multiprocessing.forkserver
import os
import statistics
import threading
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np
import numpy.typing as npt

from daemon.config import load_config
from description import thesis
from planning.interfaces import MotionPlanner, MotionRefused, MugPose, TraySlot
from planning.placement import PlanOptions, Problem, plan
from planning.placement.checked import plan_with_arm
from planning.placement.datasets import cell_dataset_problem

COLUMNS = [
    "ds",
    "layouts",
    "mugs",
    "out_of_reach",
    "planned",
    "placed",
    "order_collisions",
    "other_refusals",
    "unchecked_planned",
    "unchecked_placed",
    "unchecked_order_collisions",
    "cpu_s_per_layout",
]
_BRIM_GAP_MM = 20.0
_HANDLE_GAP_MM = 10.0
# The spacing of the points a layout's brim centres are drawn from.
_GRID_MM = 2.0


@dataclasses.dataclass(frozen=True, slots=True)
class JobRun:
    """A plan run slot by slot as the job runs it."""

    placed: int
    order_collisions: int
    other_refusals: int


def order_table(
    datasets: Sequence[int],
    layouts: int,
    seed: int,
    progress: Callable[[str], None],
    *,
    jobs: int = 1,
    unchecked: bool = True,
    log_level: str = "info",
) -> tuple[list[str], list[list[object]], dict[str, object]]:
    """The table (see the module). The layouts are drawn here, in one process and in order, so the same seed
    gives the same layouts and the same rows whatever ``jobs`` is; each layout is then planned and run in one
    of ``jobs`` worker processes (each keeps one cycle planner per dataset, with what it remembers of the
    tray's shared motions, across layouts), handed over as soon as it is drawn so the workers start on the
    first layout while the rest are drawn. ``unchecked=False`` skips the unchecked baseline (a second
    packing and job run per layout), which the order target does not need. The workers log at
    ``log_level`` to stderr, as the command line does; they and the forkserver they come from die with
    the bench, even by SIGKILL (``daemon.lifeline``)."""
    config = load_config()
    bases = {
        n: dataclasses.replace(cell_dataset_problem(config.cell, n), footprint_kind="mug") for n in datasets
    }
    mugs = {n: len(base.mugs) for n, base in bases.items()}

    def drawn() -> Iterator[tuple[int, int, Problem]]:
        for n, base in bases.items():
            rng = np.random.default_rng([seed, n])
            for k in range(layouts):
                yield n, k, random_layout(base, rng)

    runs: dict[int, list[LayoutRun]] = {n: [] for n in datasets}
    started = time.perf_counter()
    if jobs == 1:
        for n, k, problem in drawn():
            progress(f"dataset {n}: layout {k + 1} of {layouts}")
            runs[n].append(run_layout(n, problem, unchecked))
    else:
        context = multiprocessing.get_context("forkserver")
        if threading.current_thread() is threading.main_thread():
            # As the daemon's planning pool does: the forkserver dies with this process, even by SIGKILL
            # (its death signal follows the thread that started it), and each worker with the forkserver.
            context.set_forkserver_preload(["daemon.forkserver_preload"])
            multiprocessing.forkserver.ensure_running()
        with concurrent.futures.ProcessPoolExecutor(
            jobs, mp_context=context, initializer=_worker, initargs=(log_level, os.getpid())
        ) as pool:
            pending: dict[concurrent.futures.Future[LayoutRun], tuple[int, int]] = {}

            def collect(timeout: float | None) -> None:
                done, _ = concurrent.futures.wait(
                    pending, timeout=timeout, return_when=concurrent.futures.FIRST_COMPLETED
                )
                for future in done:
                    n, k = pending.pop(future)
                    progress(f"dataset {n}: layout {k + 1} of {layouts} done")
                    runs[n].append(future.result())

            for n, k, problem in drawn():
                pending[pool.submit(run_layout, n, problem, unchecked)] = (n, k)
                collect(0)
            while pending:
                collect(None)
    wall_s = time.perf_counter() - started
    rows: list[list[object]] = []
    total_checked_collisions = 0
    total_short = 0
    for n in datasets:
        rs = runs[n]

        def mean(values: Sequence[int]) -> object:
            return round(statistics.fmean(values), 2) if values else "-"

        def total(values: Sequence[int]) -> object:
            return sum(values) if values else "-"

        base_runs = [r for r in rs if r.unchecked is not None]
        rows.append(
            [
                n,
                layouts,
                mugs[n],
                mean([r.out_of_reach for r in rs]),
                mean([r.planned for r in rs]),
                mean([r.job.placed for r in rs]),
                sum(r.job.order_collisions for r in rs),
                sum(r.job.other_refusals for r in rs),
                mean([r.unchecked_planned for r in base_runs]),
                mean([r.unchecked.placed for r in base_runs if r.unchecked is not None]),
                total([r.unchecked.order_collisions for r in base_runs if r.unchecked is not None]),
                round(statistics.fmean(r.cpu_s for r in rs), 1),
            ]
        )
        total_checked_collisions += sum(r.job.order_collisions for r in rs)
        total_short += sum(r.planned - r.job.placed for r in rs)
    extra: dict[str, object] = {
        "seed": seed,
        "jobs": jobs,
        "wall_s": round(wall_s, 1),
        "planned, placed, out_of_reach": "mean per layout; collisions and refusals: sums over the layouts",
        "cpu_s_per_layout": "CPU seconds per layout in its worker (checked plan, job run, baseline)",
        "order_collisions (checked), target 0": total_checked_collisions,
        "planned but not placed (checked), target 0": total_short,
    }
    return COLUMNS, rows, extra


@dataclasses.dataclass(frozen=True, slots=True)
class LayoutRun:
    """One layout: the checked plan and its job run; the unchecked plan's (None when skipped)."""

    out_of_reach: int
    planned: int
    job: JobRun
    unchecked_planned: int
    unchecked: JobRun | None
    cpu_s: float


def _worker(log_level: str, bench_pid: int) -> None:
    from cli.logs import configure_cli_logging
    from daemon.lifeline import die_with_parent, exit_with

    die_with_parent()
    exit_with(bench_pid)
    configure_cli_logging(log_level)


# The worker's cycle planners, one per dataset (its tray), with the arm and config loaded once per process.
_PLANNERS: dict[int, tuple[MotionPlanner, tuple[float, ...]]] = {}


def _planner(n: int) -> tuple[MotionPlanner, tuple[float, ...]]:
    if n not in _PLANNERS:
        from planning.arm import ArmModel
        from planning.motion import CyclePlanner
        from sim.counter import dataset_counter

        config = load_config()
        tray = dataset_counter(n, config.cell, thesis.MUG_TYPES).tray
        arm = ArmModel.load()
        motion = CyclePlanner(arm, dataclasses.replace(config.cell, tray=tray), thesis.MUG_TYPES)
        _PLANNERS[n] = (motion, tuple(config.sim.start_q_rad))
    return _PLANNERS[n]


def run_layout(n: int, problem: Problem, unchecked: bool = True) -> LayoutRun:
    """Plan ``problem`` (dataset ``n``'s mugs at one layout) checked with the arm and run it as the job
    would; the same for the packer's unchecked plan when ``unchecked``."""
    motion, start_q = _planner(n)
    cpu = time.process_time()
    counter = [_pose(problem, i) for i in range(len(problem.mugs))]
    checked = plan_with_arm(problem, PlanOptions(), motion, start_q, counter)
    job = run_as_job(motion, start_q, checked.result.slots(problem), counter)
    base_planned, base = 0, None
    if unchecked:
        packed = plan(problem, PlanOptions())
        base_planned = packed.n
        base = run_as_job(motion, start_q, packed.slots(problem), counter)
    return LayoutRun(
        len(checked.left_out), checked.result.n, job, base_planned, base, time.process_time() - cpu
    )


def random_layout(base: Problem, rng: np.random.Generator) -> Problem:
    """``base``'s mugs at random brim centres within the box of its own counter's brim centres (see the
    module), the largest first (fewer layouts jam before the last mug), each drawn uniformly among the
    points of a ``_GRID_MM`` grid over the box that keep their distance to the mugs set out before it (as
    rejection sampling would draw it, without its misses); started again from scratch when no point is
    left for a mug."""
    xs = [m.x_mm for m in base.mugs]
    ys = [m.y_mm for m in base.mugs]
    gx = np.arange(min(xs), max(xs) + 1e-9, _GRID_MM)
    gy = np.arange(min(ys), max(ys) + 1e-9, _GRID_MM)
    grid = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
    base_xy = np.array(base.arm_base_mm, dtype=np.float64)
    types = sorted({m.type for m in base.mugs})
    radius = {t: base.mug_types[t].diameter_mm / 2.0 for t in types}
    handle = {t: base.mug_types[t].width_mm - base.mug_types[t].diameter_mm for t in types}
    while True:
        free = {t: np.arange(len(grid)) for t in types}  # indices into grid still free for a mug of type t
        at: dict[str, npt.NDArray[np.float64]] = {}
        for m in sorted(base.mugs, key=lambda m: -(radius[m.type] + handle[m.type])):
            if free[m.type].size == 0:
                break
            point = grid[free[m.type][rng.integers(free[m.type].size)]]
            at[m.id] = point
            one = point[None, :]
            r1, l1 = np.array([radius[m.type]]), np.array([handle[m.type]])
            for t in types:
                keep = _apart_all(grid[free[t]], radius[t], handle[t], one, r1, l1, base_xy)
                free[t] = free[t][keep]
        if len(at) == len(base.mugs):
            mugs = tuple(
                dataclasses.replace(m, x_mm=round(float(at[m.id][0]), 1), y_mm=round(float(at[m.id][1]), 1))
                for m in base.mugs
            )
            return dataclasses.replace(base, mugs=mugs)


def _apart_all(
    cand: npt.NDArray[np.float64],
    r: float,
    length: float,
    at: npt.NDArray[np.float64],
    r_at: npt.NDArray[np.float64],
    len_at: npt.NDArray[np.float64],
    base_xy: npt.NDArray[np.float64],
) -> npt.NDArray[np.bool_]:
    """Which candidate brim centres (K, 2) of a mug (brim radius ``r``, handle ``length``) keep their
    distance to every mug set out (``at``, their radii and handle lengths): brims ``_BRIM_GAP_MM`` apart,
    each handle (a segment from its brim pointing away from the arm base) ``_HANDLE_GAP_MM`` from the other
    mug's brim."""
    if len(at) == 0:
        return np.ones(len(cand), dtype=bool)
    d = np.linalg.norm(cand[:, None, :] - at[None, :, :], axis=2)
    ok = d >= r + r_at[None, :] + _BRIM_GAP_MM
    # A handle test can fail only for a brim within both mugs' reach (brim and handle) and the gap of the
    # other: 1 mm beyond that every handle keeps its gap by a millimetre, far beyond rounding, so only the
    # candidates within it are tested (each candidate's test is the same arithmetic as for all of them).
    reach = r + length + r_at + len_at + _HANDLE_GAP_MM + 1.0
    near = np.flatnonzero(np.all(ok, axis=1) & np.any(d < reach[None, :], axis=1))
    if near.size:
        sub = cand[near]
        k = len(sub)
        # The candidate's handle against the brims set out, then their handles against the candidate's brim.
        theirs = _handle_gap(at, r_at, len_at, sub, base_xy).T
        mine = _handle_gap(sub, np.full(k, r), np.full(k, length), at, base_xy)
        ok[near] &= (mine >= r_at[None, :] + _HANDLE_GAP_MM) & (theirs >= r + _HANDLE_GAP_MM)
    return np.asarray(np.all(ok, axis=1))


def _handle_gap(
    a: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    length: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    base_xy: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """(len(a), len(b)): distance from each point of ``b`` to the handle of each mug at ``a`` (brim radius
    ``r``, handle ``length``: a segment from its brim pointing away from the arm base)."""
    u = a - base_xy
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    p0 = (a + r[:, None] * u)[:, None, :]
    u = u[:, None, :]
    s = np.clip(np.sum((b[None, :, :] - p0) * u, axis=2), 0.0, length[:, None])
    return np.asarray(np.linalg.norm(b[None, :, :] - (p0 + s[..., None] * u), axis=2))


def _pose(problem: Problem, i: int) -> MugPose:
    from planning.arm.grasp import handle_facing_away_rad

    m = problem.mugs[i]
    x, y = m.x_mm / 1000.0, m.y_mm / 1000.0
    return MugPose(m.id, m.type, x, y, handle_yaw_rad=handle_facing_away_rad(x, y))


def run_as_job(
    motion: MotionPlanner, start_q: Sequence[float], slots: Sequence[TraySlot], counter: Sequence[MugPose]
) -> JobRun:
    """``slots`` filled in their order as the job fills them (``plan_for_slot``, a swapped mug's slot
    going to the blocked one), counting the mugs placed and why slots were refused."""
    left = {m.mug_id: m for m in counter}
    on_tray: list[TraySlot] = []
    queue = list(slots)
    q = tuple(start_q)
    placed = collisions = other = 0
    while queue:
        slot = queue.pop(0)
        if slot.mug_id not in left:
            continue
        try:
            mug, cycle = motion.plan_for_slot(q, slot, list(left.values()), on_tray)
        except MotionRefused as e:
            if "would hit mug" in str(e):
                collisions += 1
            else:
                other += 1
            continue
        if mug.mug_id != slot.mug_id:
            queue = [
                dataclasses.replace(s, mug_id=slot.mug_id) if s.mug_id == mug.mug_id else s for s in queue
            ]
        del left[mug.mug_id]
        on_tray.append(dataclasses.replace(slot, mug_id=mug.mug_id, handle_yaw_rad=cycle.handle_yaw_rad))
        placed += 1
        moves = [s.trajectory for s in cycle.steps if s.trajectory is not None]
        if moves:
            q = tuple(float(v) for v in moves[-1].positions[-1])
    return JobRun(placed, collisions, other)
