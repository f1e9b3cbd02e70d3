"""``dishbot bench placement``: every placement method on the six datasets, beside the thesis's figures.

Per dataset and method: mugs placed (mean ± sd over seeded runs), the proven optimum, a comparable cost,
wall and CPU time per run, and the thesis's run time and best count. The cost is Eq 5.2's weighted sum with
n, E and t normalised over every run of every method on that dataset, as the thesis compared its methods in
§5.3.2. A second table puts the mug-shaped planner (``footprint = "mug"``, seed 0, default budget) beside the
rectangle optimum, its upper bound and what people placed in the thesis's observational study; a third times
the fast packer against the literal occupancy-matrix packer on the same orders. ``--one-more`` adds to the
second table how close each tray is to one more mug (``planning.placement.mugrefine.one_more``). Progress
lines (case k of N, elapsed, time left) go to stderr (none with --json).
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

from cli.commands.output import add_json_flag, emit, format_table
from cli.progress import Progress
from daemon.config import load_config
from daemon.errors import UsageError
from description import thesis
from planning.placement import METHODS, PlanOptions, PlanResult, Problem, plan
from planning.placement.cost import CostFunction, Fitness, FitnessMethod, Metrics
from planning.placement.datasets import cell_dataset_problem
from planning.placement.heuristics import Heuristic
from planning.placement.packing import Packer
from planning.placement.sorts import Sort, sorted_order

METAHEURISTICS = ("sa", "ga", "psop-n", "psop-i", "psok-n", "psok-i")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "placement",
        help="placement methods on datasets 1-6 next to the thesis's results",
        description=(
            "Run every placement method on the thesis's six datasets (seeds 0..RUNS-1) and print mugs "
            "placed, cost and time per run beside the thesis's figures, then the fast packer's speed-up over "
            "the literal 1 mm occupancy-matrix packer. Times are per run on this machine; CPU time is shown "
            "too because wall time grows with whatever else the machine runs."
        ),
    )
    parser.add_argument("--runs", default="5", help="seeded runs per dataset and method (default 5)")
    parser.add_argument(
        "--methods", default=",".join(METHODS), help=f"comma-separated subset of {', '.join(METHODS)}"
    )
    parser.add_argument("--datasets", default="1,2,3,4,5,6", help="comma-separated subset of 1-6")
    parser.add_argument(
        "--time-limit", default="1.0", metavar="SEC", help="budget for auto and exact (default 1.0)"
    )
    parser.add_argument(
        "--layouts",
        default="0",
        metavar="N",
        help=(
            "instead of the method tables, check the placing order with the arm on N random counter layouts "
            "per dataset (seeded; mug-shaped footprints): cycles planned, placed as the job would place "
            "them, and order-induced collisions with and without the check (default 0: the method tables)"
        ),
    )
    parser.add_argument("--seed", default="0", help="seed of the random counter layouts (default 0)")
    parser.add_argument(
        "--jobs",
        default="1",
        metavar="J",
        help="with --layouts: worker processes checking layouts side by side (default 1; the rows do not "
        "depend on it)",
    )
    parser.add_argument(
        "--no-unchecked",
        action="store_true",
        help="with --layouts: skip the unchecked baseline (the packer's own order; a second packing and job "
        "run per layout, which the order target does not need)",
    )
    parser.add_argument(
        "--one-more",
        action="store_true",
        help="add to the mug-shaped table how close each tray is to one more mug: the count the planner "
        "packs at a smaller clearance (1 mm less at a time) and the largest clearance a continuous search "
        "from that layout keeps (below the problem's: not a valid layout; a local optimum, not a bound)",
    )
    add_json_flag(parser)
    parser.set_defaults(handler=run)


def _parse_list(text: str, allowed: tuple[str, ...], flag: str) -> list[str]:
    items = [t.strip() for t in text.split(",") if t.strip()]
    for t in items:
        if t not in allowed:
            raise UsageError(f"{flag}: unknown entry {t!r} (known: {', '.join(allowed)})")
    if not items:
        raise UsageError(f"{flag}: name at least one")
    return items


def run(args: argparse.Namespace) -> int:
    if not args.runs.isdigit() or int(args.runs) < 1:
        raise UsageError(f"--runs: expected a whole number, at least 1, got {args.runs!r}")
    n_runs = int(args.runs)
    try:
        time_limit = float(args.time_limit)
    except ValueError as e:
        raise UsageError(f"--time-limit: expected a number of seconds, got {args.time_limit!r}") from e
    if not 0 < time_limit < float("inf"):
        raise UsageError(f"--time-limit: must be positive, got {args.time_limit!r}")
    methods = _parse_list(args.methods, METHODS, "--methods")
    datasets = [
        int(d) for d in _parse_list(args.datasets, tuple(str(n) for n in thesis.DATASETS), "--datasets")
    ]
    for flag, text in (("--layouts", args.layouts), ("--seed", args.seed)):
        if not text.isdigit():
            raise UsageError(f"{flag}: expected a whole number, 0 or more, got {text!r}")
    if not args.jobs.isdigit() or int(args.jobs) < 1:
        raise UsageError(f"--jobs: expected a whole number, at least 1, got {args.jobs!r}")
    if int(args.layouts):
        from bench.placement_order import order_table

        layouts = Progress("bench placement", len(datasets) * int(args.layouts), enabled=not args.json)
        order_columns, order_rows, order_extra = order_table(
            datasets,
            int(args.layouts),
            int(args.seed),
            lambda note: layouts.next(note),
            jobs=int(args.jobs),
            unchecked=not args.no_unchecked,
            log_level=args.log_level,
        )
        emit(
            "placement order checked with the arm",
            order_columns,
            order_rows,
            as_json=args.json,
            extra=order_extra,
        )
        return 0
    rows: list[list[object]] = []
    targets = {
        "auto_optimal_within_limit": True,
        "exact_proves_all": True,
        "metaheuristics_30_mugs_max_s": 0.0,
        "metaheuristics_30_mugs_max_cpu_s": 0.0,
    }
    mug_rows: list[list[object]] = []
    progress = Progress("bench placement", len(datasets) * (2 + len(methods)) + 1, enabled=not args.json)
    for n in datasets:
        problem = cell_dataset_problem(load_config().cell, n)
        progress.next(f"dataset {n}: proving the rectangle optimum")
        optimum = plan(problem, PlanOptions(method="exact", time_limit_s=30.0))
        progress.next(f"dataset {n}: mug-shaped footprints")
        mug_rows.append(mug_shaped_row(problem, n, optimum, one_more=args.one_more))
        runs: dict[str, list[tuple[PlanResult, float, float]]] = {}
        for method in methods:
            progress.next(f"dataset {n}: {method}, {n_runs} runs")
            runs[method] = []
            for seed in range(n_runs):
                wall, cpu = time.perf_counter(), time.process_time()
                result = plan(problem, PlanOptions(method=method, seed=seed, time_limit_s=time_limit))
                runs[method].append((result, time.perf_counter() - wall, time.process_time() - cpu))
        scorer = Fitness.build(FitnessMethod.WS, CostFunction.UPC)
        for results in runs.values():
            for r, _, _ in results:
                scorer.norm.observe(_metrics(r))
        ds = thesis.DATASETS[n]
        ranks = _ranking_fitness_ranks(runs)
        for method, results in runs.items():
            placed = [r.n for r, _, _ in results]
            walls = [w for _, w, _ in results]
            cpus = [c for _, _, c in results]
            cost = statistics.fmean(scorer.value(_metrics(r)) for r, _, _ in results)
            thesis_minutes = thesis.THESIS_RUN_MINUTES.get(method)
            rows.append(
                [
                    n,
                    method,
                    _mean_sd(placed),
                    optimum.n if optimum.optimal else f"<= {optimum.upper_bound}",
                    round(cost, 3),
                    ranks[method],
                    round(statistics.median(walls), 3),
                    round(statistics.median(cpus), 3),
                    "-" if thesis_minutes is None else round(thesis_minutes[n - 1] * 60, 3),
                    ds.thesis_best_placed,
                    ds.human_placed,
                ]
            )
            if method == "auto":
                ok = all(r.optimal and r.n == optimum.n for r, _, _ in results) and max(walls) <= time_limit
                targets["auto_optimal_within_limit"] = bool(targets["auto_optimal_within_limit"]) and ok
            if method == "exact":
                targets["exact_proves_all"] = bool(targets["exact_proves_all"]) and all(
                    r.optimal for r, _, _ in results
                )
            if method in METAHEURISTICS and len(problem.mugs) == 30:
                targets["metaheuristics_30_mugs_max_s"] = max(
                    float(targets["metaheuristics_30_mugs_max_s"]), max(walls)
                )
                targets["metaheuristics_30_mugs_max_cpu_s"] = max(
                    float(targets["metaheuristics_30_mugs_max_cpu_s"]), max(cpus)
                )
    columns = [
        "ds",
        "method",
        "placed",
        "optimum",
        "ws_cost",
        "rf_rank",
        "wall_s",
        "cpu_s",
        "thesis_s",
        "thesis_best",
        "people",
    ]
    progress.next("timing the fast packer against the occupancy matrix")
    speed_columns, speed_rows = packer_speed(datasets)
    extra: dict[str, object] = {
        "runs": n_runs,
        "ws_cost": "mean Eq 5.2 weighted sum, n/E/t normalised over all runs on the dataset (lower: better)",
        "rf_rank": "rank of the mean (n, A, E, t, s) under the Eq 5.5 ranking among the methods (1 is best)",
        "wall_s, cpu_s": "median per run",
        **targets,
    }
    mug_columns = MUG_COLUMNS + (ONE_MORE_COLUMNS if args.one_more else [])
    if args.json:
        extra["mug_shaped"] = [dict(zip(mug_columns, r, strict=True)) for r in mug_rows]
        extra["packer_speed"] = [dict(zip(speed_columns, r, strict=True)) for r in speed_rows]
        emit("placement", columns, rows, as_json=True, extra=extra)
        return 0
    emit("placement", columns, rows, as_json=False, extra=extra)
    print()
    print("mug-shaped footprints (brim disc + handle as the arm turns it, 10 mm clearance) beside rectangles")
    print(format_table(mug_columns, mug_rows))
    print()
    print("fast packer vs literal 1 mm occupancy matrix (same orders, no caching)")
    print(format_table(speed_columns, speed_rows))
    return 0


MUG_COLUMNS = ["ds", "rect_optimum", "mug", "upper_bound", "people", "wall_s", "cpu_s"]
# --one-more: the count packed at a smaller clearance, that clearance, and what the refined layout keeps
ONE_MORE_COLUMNS = ["one_more", "packed_at_mm", "refined_mm"]


def mug_shaped_row(
    problem: Problem, n: int, rect_optimum: PlanResult, *, one_more: bool = False
) -> list[object]:
    """One dataset planned with mug-shaped footprints: count, its proven bound, people's figure, time;
    with ``one_more`` also ``mugrefine.one_more``'s count, packing clearance and refined clearance (mm)."""
    mug_problem = replace(problem, footprint_kind="mug")
    wall, cpu = time.perf_counter(), time.process_time()
    result = plan(mug_problem, PlanOptions())
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    more: list[object] = []
    if one_more:
        from planning.placement.mugrefine import one_more as find_one_more  # SciPy: only when asked

        found = find_one_more(mug_problem, result.n, options=PlanOptions())
        more = (
            ["-", "-", "-"]
            if found is None
            else [found.count, found.packed_at, round(found.refined.clearance, 2)]
        )
    return [
        n,
        rect_optimum.n if rect_optimum.optimal else f"<= {rect_optimum.upper_bound}",
        result.n,
        result.upper_bound,
        thesis.DATASETS[n].human_placed,
        round(wall, 2),
        round(cpu, 2),
        *more,
    ]


def packer_speed(datasets: list[int], *, repeats: int = 5) -> tuple[list[str], list[list[object]]]:
    """Median time to pack each deterministic sort order with LTF, fresh packers so no cache helps."""
    from planning.placement.oracle import GridPacker  # the literal occupancy matrix, on numpy

    columns = ["ds", "tray_mm", "orders", "grid_ms", "fast_ms", "speedup", "identical"]
    rows: list[list[object]] = []
    for n in datasets:
        problem = cell_dataset_problem(load_config().cell, n)
        orders = [sorted_order(problem, s) for s in Sort if s is not Sort.RO]
        grid_times, fast_times = [], []
        identical = True
        Packer(problem, Heuristic.LTF).pack(orders[0])  # warm up
        for _ in range(repeats):
            start = time.perf_counter()
            grid = [GridPacker(problem, Heuristic.LTF).pack(o) for o in orders]
            grid_times.append(time.perf_counter() - start)
            start = time.perf_counter()
            fast = [Packer(problem, Heuristic.LTF).pack(o) for o in orders]
            fast_times.append(time.perf_counter() - start)
            identical = identical and grid == fast
        g, f = statistics.median(grid_times), statistics.median(fast_times)
        rows.append(
            [
                n,
                "x".join(map(str, problem.tray_size_mm)),
                len(orders),
                round(g * 1000, 2),
                round(f * 1000, 3),
                round(g / f),
                identical,
            ]
        )
    return columns, rows


def _ranking_fitness_ranks(runs: dict[str, list[tuple[PlanResult, float, float]]]) -> dict[str, int]:
    """Eq 5.5 applied to each method's mean parameters: more mugs, then more area, less energy, less time,
    sorted; equal keys share a rank."""
    keys = {
        method: (
            -statistics.fmean(r.n for r, _, _ in results),
            -statistics.fmean(r.A_mm2 for r, _, _ in results),
            statistics.fmean(r.E_j for r, _, _ in results),
            statistics.fmean(r.t_s for r, _, _ in results),
            -statistics.fmean(r.s for r, _, _ in results),
        )
        for method, results in runs.items()
    }
    ordered = sorted(set(keys.values()))
    return {method: ordered.index(key) + 1 for method, key in keys.items()}


def _metrics(r: PlanResult) -> Metrics:
    return Metrics(r.n, r.A_mm2, r.E_j, r.t_s, r.s)


def _mean_sd(values: list[int]) -> str:
    mean = statistics.fmean(values)
    sd = statistics.pstdev(values) if len(values) > 1 else 0.0
    return f"{mean:.2f} ± {sd:.2f}"
