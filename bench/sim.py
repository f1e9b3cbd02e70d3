"""``dishbot bench sim``: datasets 1-3 loaded end to end in the MuJoCo cell by the daemon's own job runner.

Each dataset gets a fresh simulated cell from the daemon's own builder (``daemon.cell.open_backend``,
the cell ``dishbot run --sim --world mujoco --dataset N`` runs: the same start pose, arm calibration, mug
catalogue and detector) with its mugs on the counter where ``sim.counter`` puts them. The daemon's ``Job``
runs one loading job on it exactly as ``dishbot run --once`` does — perception on rendered depth frames, the
placement planner, the cycle planner, the real Dynamixel and FSR drivers on the in-process transport — and
the bench reads the outcome from the job's summary and the world's ground truth: mugs detected, planned,
placed (standing on the tray, upright or inverted as planned), tray collisions (the thesis's tolerance test
asks for none, Table 5.19) and how many of them were the gripper touching a mug it was not handling,
simulated time per placed mug (the thesis's Gazebo runs took about 55 s, Table 5.26), simulated and wall
time and their ratio, the wall time spent stepping the physics and the process's CPU time. The cell runs on a
simulated clock at full speed, as ``dishbot run --sim --once`` does.
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cli.commands.output import add_json_flag, emit
from cli.commands.run import association, planning_pool
from cli.progress import Progress
from daemon.config import Config, load_config
from daemon.errors import UsageError
from description import thesis
from wire.messages import Event, Payload, convert, plain

if TYPE_CHECKING:
    from daemon.clock import SimulatedClock
    from perception.interfaces import Associate
    from sim.mujoco.cell import SimCell
    from sim.mujoco.collisions import TrayCollision

DATASETS = (1, 2, 3)


@dataclass(frozen=True, slots=True)
class SimRun:
    """One dataset's job in the simulated cell."""

    dataset: int
    mugs: int
    detected: int
    planned: int
    placed: int  # the job's count
    on_tray: int  # ground truth: mugs standing on the tray at the end
    tray_collisions: int
    grasp_failures: int
    drops: int
    end_state: str
    sim_time_s: float
    wall_time_s: float
    # Of the tray collisions: the gripper touching a mug other than the one it handles (the rest are mugs
    # touching mugs).
    gripper_contacts: int = 0
    # Wall seconds the world spent stepping physics (contact monitor included), and the CPU seconds of the
    # bench's process over the job (planning's worker processes not included): on a shared machine the
    # CPU time moves less with the load than the wall time.
    stepping_s: float = float("nan")
    cpu_s: float = float("nan")

    @property
    def sim_s_per_mug(self) -> float:
        return self.sim_time_s / self.on_tray if self.on_tray else float("nan")

    @property
    def real_time_ratio(self) -> float:
        """Simulated seconds per wall second (the MuJoCo cell's target is at least 15 on dataset 1)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else float("nan")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "sim",
        help="datasets 1-3 loaded end to end in the MuJoCo cell by the daemon's job",
        description=(
            "Run one loading job per dataset in the MuJoCo cell (real drivers on simulated devices, "
            "perception on rendered depth frames) and print mugs detected, planned and placed, tray "
            "collisions (target 0), simulated seconds per placed mug, simulated and wall time and their "
            "ratio (target >= 15 on dataset 1), the wall seconds spent stepping the physics and the CPU "
            "seconds of the job. The cell runs on simulated time, as fast as the machine allows."
        ),
    )
    parser.add_argument(
        "--datasets",
        default="1,2,3",
        help="comma-separated datasets (default 1,2,3: those planned on the robot tray, the MuJoCo cell's)",
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="seed of the depth noise (default: the config's sim.seed)"
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=1800.0,
        metavar="SEC",
        help="give a job up after SEC simulated seconds (default 1800)",
    )
    parser.add_argument(
        "--fsr-debounce",
        type=float,
        default=0.03,
        metavar="SEC",
        help="how long the FSR reader waits before it believes a crossing (default 0.03, the reader's own)",
    )
    parser.add_argument("--config", type=Path, default=None, help="a config file overriding the defaults")
    add_json_flag(parser)
    parser.set_defaults(handler=run)


def _log_job_event(key: str, payload: Mapping[str, object]) -> None:
    """The job's events (grasp failures, drops, refusals, faults; not its state transitions) on stderr, so a
    run shows why mugs were not placed."""
    import structlog

    if key == "events" and convert(payload, Event, name="events").kind != "transition":
        structlog.get_logger("daemon.bench_sim").info("job_event", **{str(k): v for k, v in payload.items()})


def _datasets(text: str, config: Config) -> list[int]:
    """The datasets to run; one the MuJoCo cell cannot set out (a full-size-tray dataset) is refused with
    the message ``dishbot run --sim --world mujoco`` gives."""
    from daemon.sim_backend import mujoco_counter

    out = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        if not item.isdigit() or int(item) not in thesis.DATASETS:
            raise UsageError(f"--datasets: unknown dataset {item!r} (datasets 1-{len(thesis.DATASETS)})")
        try:
            mujoco_counter(config, int(item))
        except ValueError as e:
            raise UsageError(str(e)) from e
        out.append(int(item))
    if not out:
        raise UsageError("--datasets: name at least one of 1, 2, 3")
    return out


def run(args: argparse.Namespace) -> int:
    if not args.timeout > 0:
        raise UsageError(f"--timeout: {args.timeout} must be > 0 seconds")
    if not 0.0 <= args.fsr_debounce <= 1.0:
        raise UsageError(f"--fsr-debounce: {args.fsr_debounce} must be in [0, 1] seconds")

    from daemon.clock import SimulatedClock

    config = load_config(args.config)
    datasets = _datasets(args.datasets, config)
    with planning_pool(args.log_level) as pool:
        runs = []
        progress = Progress("bench sim", len(datasets), enabled=not args.json)
        for n in datasets:
            progress.next(f"dataset {n}")
            clock = SimulatedClock()
            run = run_dataset(
                n,
                config,
                clock=clock,
                associate=association(),
                seed=args.seed,
                timeout_s=args.timeout,
                fsr_debounce_s=args.fsr_debounce,
                executor=pool,
                on_event=_log_job_event,
            )
            runs.append(clock.run(run))
    rows = [
        [
            r.dataset,
            r.mugs,
            r.detected,
            r.planned,
            r.placed,
            r.on_tray,
            r.tray_collisions,
            r.gripper_contacts,
            r.grasp_failures,
            r.drops,
            r.end_state,
            round(r.sim_s_per_mug, 1),
            round(r.sim_time_s, 1),
            round(r.wall_time_s, 1),
            round(r.real_time_ratio, 1),
            round(r.stepping_s, 1),
            round(r.cpu_s, 1),
        ]
        for r in runs
    ]
    columns = [
        "dataset",
        "mugs",
        "detected",
        "planned",
        "placed",
        "on_tray",
        "tray_collisions",
        "gripper_contacts",
        "grasp_failures",
        "drops",
        "end_state",
        "sim_s_per_mug",
        "sim_s",
        "wall_s",
        "x_real_time",
        "stepping_s",
        "cpu_s",
    ]
    extra = {
        "fsr debounce s": args.fsr_debounce,
        "target tray_collisions": 0,
        "target gripper_contacts": 0,
        "target x_real_time": ">= 15 (dataset 1; stretch 18)",
        "thesis (Gazebo, Table 5.26) s per mug": thesis.THESIS_GAZEBO_SECONDS_PER_MUG,
        "thesis best placed (ds1, ds2, ds3)": [thesis.DATASETS[n].thesis_best_placed for n in datasets],
    }
    emit("bench sim: datasets in the MuJoCo cell", columns, rows, as_json=args.json, extra=extra)
    return 0


async def run_dataset(
    dataset: int,
    config: Config,
    *,
    clock: SimulatedClock,
    associate: Associate,
    seed: int | None = None,
    timeout_s: float = 1800.0,
    fsr_debounce_s: float = 0.03,
    executor: concurrent.futures.Executor | None = None,
    on_event: Callable[[str, Mapping[str, object]], None] | None = None,
) -> SimRun:
    """One loading job of ``dataset`` in a fresh MuJoCo cell on ``clock`` (run it with ``clock.run``),
    measured: the cell ``dishbot run --sim --world mujoco --dataset N --once`` runs
    (``daemon.cell.open_backend``), and the same job."""
    from daemon.backend import SimOptions
    from daemon.cell import open_backend
    from daemon.job import Job, StartRequest
    from daemon.job.runner import cancel_and_wait
    from daemon.sim_backend import mujoco_cell

    options = SimOptions(world="mujoco", dataset=dataset, seed=seed, fsr_debounce_s=fsr_debounce_s)
    backend = await open_backend(config, sim=options, clock=clock, executor=executor)
    cell = mujoco_cell(backend)
    collisions: list[TrayCollision] = []
    cell.on_collision(collisions.append)

    def publish(key: str, payload: Payload) -> None:
        if on_event is not None:
            on_event(key, plain(payload))

    job = Job(backend, config, publish, associate, executor=executor)
    control = asyncio.create_task(job.run())
    started = time.monotonic()
    cpu_started = time.process_time()
    try:
        sim_start = clock.monotonic()
        await job.command("start", StartRequest())
        try:
            async with clock.timeout(timeout_s):
                await job.finished.wait()
        except TimeoutError:
            await job.command("stop")
        sim_time = clock.monotonic() - sim_start
        wall = time.monotonic() - started
        cpu = time.process_time() - cpu_started
        summary = job.summary
        on_tray = _standing_on_tray(cell)
        return SimRun(
            dataset=dataset,
            mugs=len(cell.mugs),
            detected=summary.detected,
            planned=summary.planned,
            placed=summary.placed,
            on_tray=on_tray,
            tray_collisions=len(collisions),
            gripper_contacts=sum(1 for c in collisions if c.kind == "gripper_mug"),
            grasp_failures=summary.grasp_failures,
            drops=summary.drops,
            end_state=summary.end_state or "timeout",
            sim_time_s=sim_time,
            wall_time_s=wall,
            stepping_s=cell.world.wall_stepping_s,
            cpu_s=cpu,
        )
    finally:
        await job.shutdown()
        await cancel_and_wait(control)
        await backend.close()


def _standing_on_tray(cell: SimCell) -> int:
    """Mugs at rest on the tray, upright or upside down (not tipped, not held)."""
    count = 0
    for truth in cell.world.mug_truths().values():
        x, y, _ = truth.position_m
        if cell.layout.tray.contains(x, y) and truth.orientation != "tipped" and not truth.held:
            count += 1
    return count


__all__ = ["SimRun", "register", "run_dataset"]
