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

import dataclasses
import math
import random
import statistics
import time
from collections.abc import Callable, Sequence

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
    "s_per_layout",
]
_BRIM_GAP_MM = 20.0
_HANDLE_GAP_MM = 10.0


@dataclasses.dataclass(frozen=True, slots=True)
class JobRun:
    """A plan run slot by slot as the job runs it."""

    placed: int
    order_collisions: int
    other_refusals: int


def order_table(
    datasets: Sequence[int], layouts: int, seed: int, progress: Callable[[str], None]
) -> tuple[list[str], list[list[object]], dict[str, object]]:
    from planning.arm import ArmModel
    from planning.motion import CyclePlanner
    from sim.counter import dataset_counter

    config = load_config()
    arm = ArmModel.load()
    start_q = tuple(config.sim.start_q_rad)
    rows: list[list[object]] = []
    total_checked_collisions = 0
    total_short = 0
    for n in datasets:
        base = dataclasses.replace(cell_dataset_problem(config.cell, n), footprint_kind="mug")
        tray = dataset_counter(n, config.cell, thesis.MUG_TYPES).tray
        motion = CyclePlanner(arm, dataclasses.replace(config.cell, tray=tray), thesis.MUG_TYPES)
        rng = random.Random(seed * 1_000_003 + n)
        stats: dict[str, list[int]] = {c: [] for c in COLUMNS[3:11]}
        started = time.perf_counter()
        for k in range(layouts):
            progress(f"dataset {n}: layout {k + 1} of {layouts}")
            problem = random_layout(base, rng)
            counter = [_pose(problem, i) for i in range(len(problem.mugs))]
            checked = plan_with_arm(problem, PlanOptions(), motion, start_q, counter)
            run = run_as_job(motion, start_q, checked.result.slots(problem), counter)
            unchecked = plan(problem, PlanOptions())
            baseline = run_as_job(motion, start_q, unchecked.slots(problem), counter)
            for key, value in (
                ("out_of_reach", len(checked.left_out)),
                ("planned", checked.result.n),
                ("placed", run.placed),
                ("order_collisions", run.order_collisions),
                ("other_refusals", run.other_refusals),
                ("unchecked_planned", unchecked.n),
                ("unchecked_placed", baseline.placed),
                ("unchecked_order_collisions", baseline.order_collisions),
            ):
                stats[key].append(value)
            total_short += checked.result.n - run.placed
        total_checked_collisions += sum(stats["order_collisions"])
        rows.append(
            [
                n,
                layouts,
                len(base.mugs),
                round(statistics.fmean(stats["out_of_reach"]), 2),
                round(statistics.fmean(stats["planned"]), 2),
                round(statistics.fmean(stats["placed"]), 2),
                sum(stats["order_collisions"]),
                sum(stats["other_refusals"]),
                round(statistics.fmean(stats["unchecked_planned"]), 2),
                round(statistics.fmean(stats["unchecked_placed"]), 2),
                sum(stats["unchecked_order_collisions"]),
                round((time.perf_counter() - started) / layouts, 1),
            ]
        )
    extra: dict[str, object] = {
        "seed": seed,
        "planned, placed, out_of_reach": "mean per layout; collisions and refusals: sums over the layouts",
        "order_collisions (checked), target 0": total_checked_collisions,
        "planned but not placed (checked), target 0": total_short,
    }
    return COLUMNS, rows, extra


def random_layout(base: Problem, rng: random.Random) -> Problem:
    """``base``'s mugs at random brim centres within the box of its own counter's brim centres (see the
    module); tried again from scratch until every mug has a place."""
    xs = [m.x_mm for m in base.mugs]
    ys = [m.y_mm for m in base.mugs]
    box = (min(xs), min(ys), max(xs), max(ys))
    while True:
        placed: list[tuple[float, float, str]] = []
        for m in base.mugs:
            for _ in range(2000):
                x, y = rng.uniform(box[0], box[2]), rng.uniform(box[1], box[3])
                if all(_apart(base, (x, y, m.type), other) for other in placed):
                    placed.append((x, y, m.type))
                    break
            else:
                break
        if len(placed) == len(base.mugs):
            mugs = tuple(
                dataclasses.replace(m, x_mm=round(x, 1), y_mm=round(y, 1))
                for m, (x, y, _) in zip(base.mugs, placed, strict=True)
            )
            return dataclasses.replace(base, mugs=mugs)


def _apart(problem: Problem, a: tuple[float, float, str], b: tuple[float, float, str]) -> bool:
    ra = problem.mug_types[a[2]].diameter_mm / 2.0
    rb = problem.mug_types[b[2]].diameter_mm / 2.0
    if math.hypot(a[0] - b[0], a[1] - b[1]) < ra + rb + _BRIM_GAP_MM:
        return False
    return (
        _handle_gap(problem, a, b) >= rb + _HANDLE_GAP_MM
        and _handle_gap(problem, b, a) >= ra + _HANDLE_GAP_MM
    )


def _handle_gap(problem: Problem, a: tuple[float, float, str], b: tuple[float, float, str]) -> float:
    """Distance from ``b``'s axis to ``a``'s handle (a segment from its brim to its tip, pointing away
    from the arm base)."""
    t = problem.mug_types[a[2]]
    r = t.diameter_mm / 2.0
    bx, by = problem.arm_base_mm
    yaw = math.atan2(a[1] - by, a[0] - bx)
    ux, uy = math.cos(yaw), math.sin(yaw)
    p0 = (a[0] + r * ux, a[1] + r * uy)
    length = t.width_mm - t.diameter_mm
    s = max(0.0, min(length, (b[0] - p0[0]) * ux + (b[1] - p0[1]) * uy))
    return math.hypot(b[0] - (p0[0] + s * ux), b[1] - (p0[1] + s * uy))


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
