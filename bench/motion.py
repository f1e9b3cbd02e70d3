"""``dishbot bench motion``: inverse kinematics, trajectory generation and the per-mug cycle on a dataset.

IK is measured on targets known to be reachable: forward kinematics of seeded random joint poses inside the
limits (position-only targets), and of random side-grasp poses (horizontal, upright or upside down) for the
grasp targets, so the success rate measures the solver, not the workspace. The cycle part plans the thesis's
dataset in the default cell the way the daemon does: the placement planner's layout and order, each slot
served by the named mug or another reachable one of its type, every cycle collision-checked (datasets 4-6 on
the full-size tray, where many slots are out of the arm's reach). Per mug it reports the cycle time and the
electrical energy of the dynamics model (RNEA + servo model, with and without the servos' standby draw)
beside the thesis's proxy E = M g Δm (Eq 4.2), and how long a slot no mug can be moved to takes to refuse.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from cli.commands.output import add_json_flag, emit
from daemon.config import load_config
from daemon.errors import UsageError
from description import thesis
from planning.interfaces import MotionRefused, MugPose, StepKind, TraySlot

if TYPE_CHECKING:
    import numpy as np

    from planning.arm import ArmModel, GraspTarget


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "motion",
        help="IK success and speed, trajectory generation, cycle time and energy per mug",
        description=(
            "Measure the arm's inverse kinematics (success rate, residual, time p50/p99) on reachable "
            "targets, trajectory generation time, and the cycle time and energy per mug when loading a "
            "thesis dataset in the default cell (both energy models side by side). Times are wall-clock "
            "on this machine; IK CPU time is shown too, as wall time grows with whatever else runs."
        ),
    )
    parser.add_argument("--samples", default="400", help="IK targets per kind (default 400)")
    parser.add_argument(
        "--dataset",
        default="1",
        help="thesis dataset: 1, 2 or 3 on the robot tray, 4, 5 or 6 on the full-size tray (default 1)",
    )
    parser.add_argument("--seed", default="0", help="random seed for the IK samples (default 0)")
    add_json_flag(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    samples = _whole("--samples", args.samples, minimum=10)
    seed = _whole("--seed", args.seed, minimum=0)
    if args.dataset not in ("1", "2", "3", "4", "5", "6"):
        raise UsageError(f"--dataset: expected a thesis dataset, 1 to 6, got {args.dataset!r}")
    import numpy as np

    from planning.arm import ArmModel

    arm = ArmModel.load()
    rows: list[list[object]] = []
    extra: dict[str, object] = {}
    rng = np.random.default_rng(seed)
    for label, targets in (
        ("position", _position_targets(arm, rng, samples)),
        ("side grasp", _side_targets(arm, rng, samples)),
    ):
        ok, residuals, wall, cpu = _ik_run(arm, targets)
        rows.append([f"IK success ({label})", round(100.0 * ok / len(targets), 2), "%", "reachable targets"])
        rows.append(
            [f"IK residual max ({label})", round(max(residuals, default=math.nan) * 1000, 4), "mm", "<= 1 mm"]
        )
        rows.append([f"IK time p50 ({label})", round(_pct(wall, 50) * 1000, 3), "ms", "<= 2 ms"])
        rows.append([f"IK time p99 ({label})", round(_pct(wall, 99) * 1000, 3), "ms", "<= 2 ms"])
        rows.append([f"IK CPU time p99 ({label})", round(_pct(cpu, 99) * 1000, 3), "ms", "<= 2 ms"])
    move_times = _trajectory_times(arm, rng, 100)
    rows.append(["trajectory generation p50 (joint move)", round(_pct(move_times, 50) * 1000, 3), "ms", ""])
    rows.append(["trajectory generation p99 (joint move)", round(_pct(move_times, 99) * 1000, 3), "ms", ""])
    cycle = _dataset_cycles(arm, int(args.dataset))
    rows += cycle.pop("rows")  # type: ignore[arg-type]
    extra.update(cycle)
    extra["samples_per_kind"] = samples
    emit("bench motion", ("metric", "value", "unit", "reference"), rows, as_json=args.json, extra=extra)
    return 0


def _whole(flag: str, text: str, *, minimum: int) -> int:
    if not text.isdigit() or int(text) < minimum:
        raise UsageError(f"{flag}: expected a whole number, at least {minimum}, got {text!r}")
    return int(text)


def _pct(values: Sequence[float], q: float) -> float:
    import numpy as np

    return float(np.percentile(values, q)) if len(values) else math.nan


def _position_targets(arm: ArmModel, rng: np.random.Generator, n: int) -> list[GraspTarget]:
    from planning.arm import GraspTarget

    out: list[GraspTarget] = []
    while len(out) < n:
        q = rng.uniform(arm.lower, arm.upper)
        position, _ = arm.fk(q)
        if position[2] > 0.02:  # above the counter
            out.append(GraspTarget((float(position[0]), float(position[1]), float(position[2]))))
    return out


def _side_targets(arm: ArmModel, rng: np.random.Generator, n: int) -> list[GraspTarget]:
    """FK of horizontal-approach poses: the lifts sum to -pi/2, the wrist turned to +-pi/2."""
    from planning.arm import GraspKind, GraspTarget

    out: list[GraspTarget] = []
    while len(out) < n:
        q = rng.uniform(arm.lower, arm.upper)
        q[3] = -math.pi / 2 - q[1] - q[2]
        upside_down = bool(rng.integers(2))
        q[4] = -math.pi / 2 if upside_down else math.pi / 2
        if arm.limit_violations(q):
            continue
        position, rotation = arm.fk(q)
        if position[2] <= 0.02 or math.hypot(position[0], position[1]) < 0.1:
            continue
        # A side grasp approaches away from the shoulder axis (Eq 4.28); leaning back over the shoulder
        # the gripper would face the base instead, which is not a side-grasp target.
        if float(position[:2] @ rotation[:2, 2]) <= 0.0:
            continue
        kind = GraspKind.SIDE_UPSIDE_DOWN if upside_down else GraspKind.SIDE
        out.append(GraspTarget((float(position[0]), float(position[1]), float(position[2])), kind))
    return out


def _ik_run(
    arm: ArmModel, targets: Sequence[GraspTarget]
) -> tuple[int, list[float], list[float], list[float]]:
    """Successes, residuals of the successes, wall times and CPU times (this thread) per call."""
    ok = 0
    residuals: list[float] = []
    wall: list[float] = []
    cpu: list[float] = []
    for target in targets:
        t0, c0 = time.perf_counter(), time.thread_time()
        result = arm.ik(target)
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
        if result.ok:
            ok += 1
            residuals.append(result.residual_m)
    return ok, residuals, wall, cpu


def _trajectory_times(arm: ArmModel, rng: np.random.Generator, n: int) -> list[float]:
    import numpy as np

    from planning.motion import plan_path

    times = []
    for _ in range(n):
        a, b = rng.uniform(arm.lower, arm.upper), rng.uniform(arm.lower, arm.upper)
        t0 = time.perf_counter()
        plan_path(
            np.array([a, b]),
            names=arm.joint_names,
            max_velocity=arm.max_velocity,
            max_acceleration=arm.max_acceleration,
            rate_hz=50.0,
            label="bench",
        )
        times.append(time.perf_counter() - t0)
    return times


def _dataset_cycles(arm: ArmModel, dataset: int) -> dict[str, object]:
    from planning.arm.grasp import handle_facing_away_rad
    from planning.motion import CyclePlanner, thesis_energy_j
    from planning.placement import PlanOptions, cell_dataset_problem, plan
    from sim.counter import dataset_counter

    config = load_config()
    problem = cell_dataset_problem(config.cell, dataset)
    # Datasets 4-6 go to the full-size tray, where the kinematic cell sets them out.
    tray = dataset_counter(dataset, config.cell, thesis.MUG_TYPES).tray
    planner = CyclePlanner(arm, dataclasses.replace(config.cell, tray=tray), thesis.MUG_TYPES)
    layout = plan(problem, PlanOptions(method="sa", time_limit_s=1.0))
    counter = {}
    for m in problem.mugs:
        x, y = m.x_mm / 1000.0, m.y_mm / 1000.0
        counter[m.id] = MugPose(m.id, m.type, x, y, handle_yaw_rad=handle_facing_away_rad(x, y))
    q: Sequence[float] = config.sim.start_q_rad
    placed: list[TraySlot] = []
    durations, dyn_motion, dyn_total, proxy, plan_times = [], [], [], [], []
    refused: list[str] = []
    refusal_times: list[float] = []
    refusal_cpu: list[float] = []
    for spot in sorted(layout.placed, key=lambda p: p.order):
        cx, cy = problem.to_world_mm(*problem.brim_centre_on_tray(spot.type, spot.x_mm, spot.y_mm))
        slot = TraySlot(spot.id, spot.type, cx / 1000.0, cy / 1000.0, spot.rotated)
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            mug, cycle = planner.plan_for_slot(q, slot, list(counter.values()), placed)
        except MotionRefused as e:
            refusal_cpu.append(time.thread_time() - c0)
            refusal_times.append(time.perf_counter() - t0)
            refused.append(f"{spot.id}: {str(e)[:160]}")
            continue
        plan_times.append(time.perf_counter() - t0)
        counter.pop(mug.mug_id)
        placed.append(TraySlot(mug.mug_id, mug.type, slot.x_m, slot.y_m))
        moves = [s for s in cycle.steps if s.kind is StepKind.MOVE and s.trajectory is not None]
        q = tuple(float(v) for v in moves[-1].trajectory.positions[-1])  # type: ignore[union-attr]
        durations.append(cycle.duration_s)
        dyn_total.append(cycle.energy_j)
        dyn_motion.append(cycle.energy_j - planner.energy_model.idle_energy_j(cycle.duration_s))
        mass = thesis.MUG_TYPES[mug.type].mass_kg
        proxy.append(thesis_energy_j(mass, (mug.x_m, mug.y_m), (slot.x_m, slot.y_m)))
    n = len(durations)
    rows: list[list[object]] = [
        [f"mugs moved (dataset {dataset})", n, "mugs", f"{layout.n} planned by the placement planner"],
        ["cycle planning p50", round(_pct(plan_times, 50), 3), "s", "thesis: < 60 s"],
        [f"slots refused (dataset {dataset})", len(refused), "slots", "no mug can be moved there"],
        ["refused slot p50", round(_pct(refusal_times, 50), 3), "s", "<= 0.1 s"],
        ["refused slot max", round(max(refusal_times, default=math.nan), 3), "s", "<= 0.1 s"],
        ["refused slot CPU time p50", round(_pct(refusal_cpu, 50), 3), "s", "<= 0.1 s"],
        ["refused slot CPU time max", round(max(refusal_cpu, default=math.nan), 3), "s", "<= 0.1 s"],
        [
            "cycle time per mug (mean)",
            round(statistics.fmean(durations), 2) if n else math.nan,
            "s",
            "< 180 s; Gazebo ~55 s",
        ],
        ["cycle time per mug (max)", round(max(durations), 2) if n else math.nan, "s", "< 180 s"],
        [
            "energy per mug, dynamics, motion",
            round(statistics.fmean(dyn_motion), 1) if n else math.nan,
            "J",
            "RNEA + servo model",
        ],
        [
            "energy per mug, dynamics, with standby",
            round(statistics.fmean(dyn_total), 1) if n else math.nan,
            "J",
            "adds 6 W servo standby",
        ],
        [
            "energy per mug, thesis proxy M g dm",
            round(statistics.fmean(proxy), 3) if n else math.nan,
            "J",
            "Eq 4.2",
        ],
    ]
    return {"rows": rows, "refused": refused, "dataset": dataset}
