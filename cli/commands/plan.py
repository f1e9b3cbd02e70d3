"""``dishbot plan``: plan where each mug goes on the tray, from a problem file or a built-in dataset.

It imports what the run needs when it needs it: the config only for a dataset or a footprint the problem
leaves open, the renderer (and OpenCV) only for pictures."""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

from daemon.errors import UsageError
from description import thesis
from planning.placement import (
    FOOTPRINTS,
    METHODS,
    InvalidProblem,
    PlanOptions,
    PlanResult,
    Problem,
    plan,
)
from planning.placement.heuristics import Heuristic
from planning.placement.sorts import Sort


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "plan",
        help="plan the mugs' tray positions and placing order",
        description=(
            "Plan where each counter mug goes on the dishwasher tray and in which order the arm places them. "
            "The problem is a JSON file (format in the README) or one of the thesis's datasets 1-6. "
            "Prints a summary, or the result as JSON with --json; --svg/--png also draw the tray."
        ),
    )
    parser.add_argument(
        "problem", nargs="?", metavar="PROBLEM.json", help="the placement problem ('-' = stdin)"
    )
    parser.add_argument(
        "--dataset", metavar="N", help="a built-in dataset of the thesis (1-6) instead of a file"
    )
    parser.add_argument(
        "--method",
        default="auto",
        help=f"placement method: {', '.join(METHODS)} (default auto: the best within the time limit)",
    )
    parser.add_argument(
        "--heuristic",
        default="ltf",
        help=f"fill order: {', '.join(h.value for h in Heuristic)} (default ltf, left-top fill)",
    )
    parser.add_argument(
        "--sort",
        help=f"initial order: {', '.join(s.value for s in Sort)} (default: every sort for bh/auto, nis-l for"
        " the optimisers)",
    )
    parser.add_argument("--fitness", default="rf", help="ws (weighted sum) or rf (ranking, default)")
    parser.add_argument(
        "--cost", default="upc", help="bpc (bin packing), upc (user preference, default) or ec (engineering)"
    )
    parser.add_argument(
        "--weights",
        metavar="n=W,E=W,t=W,s=W",
        help="your own weighted-sum weights (default: Eq 5.2 for upc, Eq 5.3 for ec)",
    )
    parser.add_argument(
        "--ranking",
        metavar="P,P,...",
        help="your own ranking of n, E, t, s for --fitness rf (default n,E,t,s; area always follows n)",
    )
    parser.add_argument(
        "--footprint",
        metavar="|".join(FOOTPRINTS),
        help="mug model: rect (the thesis's rectangles) or mug (brim disc plus handle as the arm turns it);"
        " default: the problem file's, else the config's [planner] footprint",
    )
    parser.add_argument("--seed", default="0", help="random seed, a whole number (default 0)")
    parser.add_argument(
        "--time-limit",
        default="1.0",
        metavar="SEC",
        help="budget for auto and exact in seconds (default 1.0)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help="config whose cell places the --dataset mugs on the counter (default: the embedded one)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as one JSON document")
    parser.add_argument("--svg", type=Path, metavar="FILE", help="also draw the plan as SVG")
    parser.add_argument("--png", type=Path, metavar="FILE", help="also draw the plan as PNG")
    parser.set_defaults(handler=run)


def load_problem(args: argparse.Namespace) -> Problem:
    """The problem to plan, with the footprint ``--footprint``, the file or the config asks for."""
    from daemon.config import load_cell_and_planner  # only for a dataset or the config's footprint

    if args.footprint is not None and args.footprint not in FOOTPRINTS:
        raise UsageError(
            f"--footprint: unknown footprint {args.footprint!r} (known: {', '.join(FOOTPRINTS)})"
        )
    if args.dataset is not None:
        if args.problem is not None:
            raise UsageError("give either PROBLEM.json or --dataset N, not both")
        known = {str(n): n for n in thesis.DATASETS}
        if args.dataset not in known:
            raise UsageError(f"--dataset: unknown dataset {args.dataset!r} (known: 1-{len(thesis.DATASETS)})")
        from planning.placement.datasets import cell_dataset_problem

        cell, planner = load_cell_and_planner(args.config)
        problem = cell_dataset_problem(cell, known[args.dataset])
        return _with_footprint(problem, args.footprint or planner.footprint)
    if args.problem is None:
        raise UsageError("give a PROBLEM.json (or - for stdin) or --dataset N")
    name = args.problem
    try:
        text = sys.stdin.read() if name == "-" else Path(name).read_text(encoding="utf-8")
    except FileNotFoundError as e:
        raise UsageError(f"{name}: no such file") from e
    except (OSError, UnicodeDecodeError) as e:
        raise UsageError(f"{name}: cannot read: {e}") from e
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise UsageError(f"{name}: not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from e
    try:
        problem = Problem.from_json(doc)
    except InvalidProblem as e:
        raise UsageError(f"{name}: {e}") from e
    if args.footprint is not None:
        return _with_footprint(problem, args.footprint, name)
    if isinstance(doc, dict) and "footprint" in doc:
        return problem
    return _with_footprint(problem, load_cell_and_planner(args.config)[1].footprint, name)


def _with_footprint(problem: Problem, footprint: str, where: str = "--footprint") -> Problem:
    try:
        return replace(problem, footprint_kind=footprint)
    except InvalidProblem as e:
        raise UsageError(f"{where}: {e}") from e


def run(args: argparse.Namespace) -> int:
    # One short run that leaves next to no garbage in cycles (the plan's objects are freed by their reference
    # counts; its peak memory is the same either way): the cyclic collector's passes over the modules it
    # imports and the packer's many small tuples cost about 5 % of a plan's CPU, so it waits until the end.
    collecting = gc.isenabled()
    gc.disable()
    try:
        return _run(args)
    finally:
        if collecting:
            gc.enable()


def _load_numpy_single_threaded() -> None:
    """Loads numpy, which every plan computes with, with its BLAS library on one thread.

    OpenBLAS starts a thread per core when it loads, and they spin for a while waiting for work: a third
    of numpy's import in CPU time (about 30 ms of a plan's). The planner does no linear algebra (its
    arrays are masks, sorts and element-wise distances), so it has no use for them. The variable is read
    only as the library loads, and put back at once: nothing else in the process sees it changed."""
    if "numpy" in sys.modules:
        return
    name = "OPENBLAS_NUM_THREADS"
    before = os.environ.get(name)
    os.environ[name] = "1"
    try:
        import numpy  # noqa: F401  (loaded here, under the variable)
    finally:
        if before is None:
            del os.environ[name]
        else:
            os.environ[name] = before


def _run(args: argparse.Namespace) -> int:
    time_limit = _number("--time-limit", args.time_limit, float)
    if not 0 < time_limit < float("inf"):
        raise UsageError(f"--time-limit: must be a positive number of seconds, got {args.time_limit!r}")
    seed = int(_number("--seed", args.seed, int))
    for flag, path in (("--svg", args.svg), ("--png", args.png)):
        if path is not None and not path.parent.resolve().is_dir():
            raise UsageError(f"{flag}: directory {str(path.parent)!r} does not exist")
    _load_numpy_single_threaded()
    problem = load_problem(args)
    from planning.placement.cache import default_dir

    options = PlanOptions(
        method=args.method,
        heuristic=args.heuristic,
        sort=args.sort,
        fitness=args.fitness,
        cost=args.cost,
        seed=seed,
        time_limit_s=time_limit,
        weights=_weights(args.weights),
        ranking=None if args.ranking is None else tuple(p.strip() for p in args.ranking.split(",")),
        cache_dir=default_dir(),  # rectangle optima and scan orders kept between runs: the same plan, sooner
    )
    try:
        result = plan(problem, options)
    except InvalidProblem as e:
        message = str(e)
        for option in ("method", "heuristic", "sort", "fitness", "cost"):
            if message.startswith(f"{option}: "):
                message = "--" + message
        raise UsageError(message) from e
    # Render everything before writing anything, so a failure leaves no half-written output.
    outputs: list[tuple[Path, bytes]] = []
    if args.svg is not None or args.png is not None:
        from cli.pictures import png_with_text, write_atomically
        from planning.placement.render import to_png, to_svg
    if args.svg is not None:
        outputs.append((args.svg, to_svg(problem, result).encode()))
    if args.png is not None:
        outputs.append((args.png, png_with_text(to_png(problem, result), picture_text(problem, result))))
    for path, data in outputs:
        write_atomically(path, data)
    if args.json:
        json.dump(result.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(summary(result))
    return 0


def _number(flag: str, text: str, kind: type[int] | type[float]) -> float:
    try:
        return kind(text)
    except ValueError as e:
        what = "a whole number" if kind is int else "a number"
        raise UsageError(f"{flag}: expected {what}, got {text!r}") from e


def _weights(text: str | None) -> dict[str, float] | None:
    if text is None:
        return None
    weights: dict[str, float] = {}
    for part in text.split(","):
        name, sep, value = part.partition("=")
        try:
            weights[name.strip()] = float(value)
        except ValueError as e:
            raise UsageError(f"--weights: expected name=number pairs like n=0.4,E=0.3, got {part!r}") from e
        if not sep:
            raise UsageError(f"--weights: expected name=number pairs like n=0.4,E=0.3, got {part!r}")
    return weights


def summary(result: PlanResult) -> str:
    total = result.n + len(result.unplaced)
    proof = ""
    if result.optimal:
        proof = " (proven optimal)"
    elif result.upper_bound is not None:
        proof = f" (at most {result.upper_bound} fit)"
    lines = [
        f"{result.method}: {result.n} of {total} mugs placed{proof} in {result.wall_time_s:.3f} s",
        f"area {result.A_mm2:.0f} mm², energy {result.E_j:.2f} J, time {result.t_s:.1f} s, sorted {result.s},"
        f" cost {result.cost:.4f}",
        "order  id        type    x_mm  y_mm  rotated",
    ]
    lines += [
        f"{p.order:5d}  {p.id:<8}  {p.type:<6}  {p.x_mm:4d}  {p.y_mm:4d}  {str(p.rotated).lower()}"
        for p in result.placed
    ]
    if result.unplaced:
        lines.append("left on the counter: " + ", ".join(result.unplaced))
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def picture_text(problem: Problem, result: PlanResult) -> dict[str, str]:
    """What the plan's picture shows, in words (its PNG ``tEXt``): the tray's size and units, each mug."""
    tx, ty = problem.tray_size_mm
    placed = "; ".join(f"{p.order} {p.id} ({p.type}) at x {p.x_mm} y {p.y_mm} mm" for p in result.placed)
    lines = [
        f"Top view of the tray, {tx} x {ty} mm (x away from the arm, up; y to the arm's left, left); "
        "lengths in mm; a mug's x and y: its footprint's corner, from the tray's origin corner",
        f"placed in this order: {placed or 'none'}",
    ]
    if problem.placed:
        lines.append("already on the tray (grey): " + ", ".join(q.id for q in problem.placed))
    if problem.strays:
        strays = ", ".join(q.id for q in problem.strays)
        lines.append(f"lying on the tray where no plan put them (grey): {strays}")
    if result.unplaced:
        lines.append("left on the counter: " + ", ".join(result.unplaced))
    title = f"dishbot plan: {result.method}, {result.n} of {result.n + len(result.unplaced)} mugs on the tray"
    return {"Title": title, "Description": "\n".join(lines), "Software": "dishbot plan"}
