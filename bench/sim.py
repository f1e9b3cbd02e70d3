"""``dishbot bench sim``: datasets 1-3 loaded end to end in the MuJoCo cell by the daemon's own job runner.

Each dataset gets a fresh simulated cell (``sim.mujoco.cell``) with its mugs on the counter where the
placement datasets put them. The daemon's ``Job`` runs one loading job on it exactly as ``dishbot run --sim``
does — perception on rendered depth frames, the placement planner, the cycle planner, the real Dynamixel and
FSR drivers over pseudo-terminals — and the bench reads the outcome from the job's summary and the world's
ground truth: mugs detected, planned, placed (standing on the tray, upright or inverted as planned), tray
collisions (the thesis's tolerance test asks for none, Table 5.19), simulated time per placed mug (the
thesis's Gazebo runs took about 55 s, Table 5.26), simulated and wall time and their ratio. The cell runs
in-process on a simulated clock at full speed (``dishbot run --sim --once`` does the same).
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import contextlib
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import structlog

from daemon.backend import Backend, CounterMug, CyclePlannerSpec, ProcessMotionPlanner, Tray
from daemon.clock import SimulatedClock
from daemon.commands.output import add_json_flag, emit
from daemon.commands.run import planning_pool
from daemon.config import Config, load_config
from daemon.errors import UsageError
from daemon.job import Associate, Job, StartRequest
from description import thesis
from description.cell import SceneLayout
from description.thesis import MugSpec
from drivers.interfaces import Camera
from perception import CameraObserver, DepthMugDetector, associate
from perception.interfaces import MugObserver
from planning.placement import dataset_problem
from sim.mujoco.cell import ObserverFactory, SimCell, scene_mugs, start_sim_cell
from sim.mujoco.collisions import TrayCollision

DATASETS = (1, 2, 3)

log = structlog.get_logger("daemon.bench_sim")


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

    @property
    def sim_s_per_mug(self) -> float:
        return self.sim_time_s / self.on_tray if self.on_tray else float("nan")

    @property
    def real_time_ratio(self) -> float:
        """Simulated seconds per wall second (the MuJoCo cell's target is at least 5)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else float("nan")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "sim",
        help="datasets 1-3 loaded end to end in the MuJoCo cell by the daemon's job",
        description=(
            "Run one loading job per dataset in the MuJoCo cell (real drivers on simulated devices, "
            "perception on rendered depth frames) and print mugs detected, planned and placed, tray "
            "collisions (target 0), simulated seconds per placed mug, simulated and wall time and their "
            "ratio (target >= 5). The cell runs on simulated time, as fast as the machine allows."
        ),
    )
    parser.add_argument("--datasets", default="1,2,3", help="comma-separated subset of 1,2,3 (default all)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the depth noise and the planners")
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
    if key == "events" and payload.get("kind") != "transition":
        log.info("job_event", **{str(k): v for k, v in payload.items()})


def _datasets(text: str) -> list[int]:
    out = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        if not item.isdigit() or int(item) not in DATASETS:
            raise UsageError(f"--datasets: unknown dataset {item!r} (the simulated cell runs 1, 2 and 3)")
        out.append(int(item))
    if not out:
        raise UsageError("--datasets: name at least one of 1, 2, 3")
    return out


def run(args: argparse.Namespace) -> int:
    datasets = _datasets(args.datasets)
    if not args.timeout > 0:
        raise UsageError(f"--timeout: {args.timeout} must be > 0 seconds")
    if not 0.0 <= args.fsr_debounce <= 1.0:
        raise UsageError(f"--fsr-debounce: {args.fsr_debounce} must be in [0, 1] seconds")
    config = load_config(args.config)
    detector = DepthMugDetector(catalogue_of(config))

    def observer_factory(camera: Camera) -> MugObserver:
        return CameraObserver(camera, detector)

    with planning_pool(args.log_level) as pool:
        runs = []
        for n in datasets:
            clock = SimulatedClock()
            run = run_dataset(
                n,
                config,
                clock=clock,
                observer_factory=observer_factory,
                associate=associate,
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
            r.grasp_failures,
            r.drops,
            r.end_state,
            round(r.sim_s_per_mug, 1),
            round(r.sim_time_s, 1),
            round(r.wall_time_s, 1),
            round(r.real_time_ratio, 1),
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
        "grasp_failures",
        "drops",
        "end_state",
        "sim_s_per_mug",
        "sim_s",
        "wall_s",
        "x_real_time",
    ]
    extra = {
        "fsr debounce s": args.fsr_debounce,
        "target tray_collisions": 0,
        "target x_real_time": ">= 5",
        "thesis (Gazebo, Table 5.26) s per mug": thesis.THESIS_GAZEBO_SECONDS_PER_MUG,
        "thesis best placed (ds1, ds2, ds3)": [thesis.DATASETS[n].thesis_best_placed for n in datasets],
    }
    emit("bench sim: datasets in the MuJoCo cell", columns, rows, as_json=args.json, extra=extra)
    return 0


def catalogue_of(config: Config) -> dict[str, MugSpec]:
    return {
        m.name: MugSpec(m.name, m.diameter_mm, m.width_mm, m.height_mm, m.mass_kg) for m in config.mug_types
    }


def layout_of(config: Config) -> SceneLayout:
    """The simulated cell's layout from the config's ``[cell]`` and ``[camera]`` sections."""
    from description.camera import CameraSpec

    c, cam = config.cell, config.camera
    return SceneLayout(
        counter_region_m=c.counter_region_m,
        flip_area_center_m=c.flip_area_center_m,
        flip_area_radius_m=c.flip_area_radius_m,
        tray_origin_m=c.tray_origin_m,
        tray_size_mm=c.tray_size_mm,
        camera=CameraSpec(cam.width, cam.height, cam.fovy_deg, cam.position_m, cam.yaw_rad, cam.pitch_rad),
        table_height_above_floor_m=c.table_height_above_floor_m,
    )


class MujocoCounter:
    """Sets the MuJoCo cell's counter up for a job (``daemon.backend.CounterSetup``): a placement dataset's
    mugs where ``planning.placement.dataset_problem`` puts them, or an explicit list."""

    def __init__(self, cell: SimCell, config: Config) -> None:
        self._cell = cell
        self._config = config
        self._catalogue = catalogue_of(config)
        self.tray = Tray(config.cell.tray_origin_m, config.cell.tray_size_mm)

    def set_counter(self, *, dataset: int | None, mugs: Sequence[CounterMug] | None) -> Tray:
        if mugs is None:
            n = dataset or 1
            if thesis.DATASETS[n].tray_mm != thesis.ROBOT_TRAY_MM:
                raise ValueError(
                    f"dataset {n} needs the full-size tray, which the simulated cell does not have"
                )
            problem = dataset_problem(
                n,
                counter_region_m=self._config.cell.counter_region_m,
                tray_origin_m=self._config.cell.tray_origin_m,
            )
            entries = [(m.id, m.type, m.x_mm / 1000.0, m.y_mm / 1000.0) for m in problem.mugs]
        else:
            entries = [(m.mug_id, m.type, m.x_m, m.y_m) for m in mugs]
        self._cell.set_counter(scene_mugs(entries, self._catalogue))
        return self.tray

    def scene(self) -> dict[str, object]:
        return self._cell.scene()


async def open_mujoco_backend(
    config: Config,
    *,
    clock: SimulatedClock,
    observer_factory: ObserverFactory,
    seed: int = 0,
    fsr_debounce_s: float = 0.03,
    executor: concurrent.futures.Executor | None = None,
) -> tuple[Backend, SimCell]:
    """A daemon backend on a fresh MuJoCo cell (empty counter; a job's ``start`` puts the mugs on it), on
    ``clock``.

    With ``executor`` (a process pool) motion planning runs there, as in ``dishbot run``: in this process it
    would hold the GIL against the event loop that steps the physics and serves the device simulators."""
    layout = layout_of(config)
    cell, close = await start_sim_cell(
        layout,
        [],
        clock=clock,
        seed=seed,
        start_pose_rad=config.sim.start_q_rad,
        # As the kinematic cell: "holding" at half the grasp threshold.
        holding_threshold_n=config.grasp.force_threshold_n / 2.0,
        fsr_debounce_s=fsr_debounce_s,
        observer_factory=observer_factory,
    )
    counter = MujocoCounter(cell, config)
    spec = CyclePlannerSpec(config.cell, counter.tray, config.mug_types)
    motion = spec.build() if executor is None else ProcessMotionPlanner(spec, executor)
    backend = Backend(
        name="sim-mujoco",
        arm=cell.arm,
        gripper=cell.gripper,
        force=cell.force,
        observer=cell.observer,
        motion=motion,
        tray=counter.tray,
        counter=counter,
        closer=close,
        clock=clock,
    )
    return backend, cell


async def run_dataset(
    dataset: int,
    config: Config,
    *,
    clock: SimulatedClock,
    observer_factory: ObserverFactory,
    associate: Associate,
    seed: int = 0,
    timeout_s: float = 1800.0,
    fsr_debounce_s: float = 0.03,
    executor: concurrent.futures.Executor | None = None,
    on_event: Callable[[str, Mapping[str, object]], None] | None = None,
) -> SimRun:
    """One loading job of ``dataset`` in a fresh MuJoCo cell on ``clock`` (run it with ``clock.run``),
    measured."""
    backend, cell = await open_mujoco_backend(
        config,
        clock=clock,
        observer_factory=observer_factory,
        seed=seed,
        fsr_debounce_s=fsr_debounce_s,
        executor=executor,
    )
    collisions: list[TrayCollision] = []
    cell.on_collision(collisions.append)

    def publish(key: str, payload: Mapping[str, object]) -> None:
        if on_event is not None:
            on_event(key, payload)

    job = Job(backend, config, publish, associate, executor=executor)
    control = asyncio.create_task(job.run())
    started = time.monotonic()
    try:
        sim_start = clock.monotonic()
        await job.command("start", StartRequest(dataset=dataset))
        try:
            async with clock.timeout(timeout_s):
                await job.finished.wait()
        except TimeoutError:
            await job.command("stop")
        sim_time = clock.monotonic() - sim_start
        wall = time.monotonic() - started
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
            grasp_failures=summary.grasp_failures,
            drops=summary.drops,
            end_state=summary.end_state or "timeout",
            sim_time_s=sim_time,
            wall_time_s=wall,
        )
    finally:
        await job.shutdown()
        control.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await control
        await backend.close()


def _standing_on_tray(cell: SimCell) -> int:
    """Mugs at rest on the tray, upright or upside down (not tipped, not held)."""
    x0, y0, x1, y1 = cell.layout.tray_region_m()
    count = 0
    for truth in cell.world.mug_truths().values():
        x, y, _ = truth.position_m
        if x0 <= x <= x1 and y0 <= y <= y1 and truth.orientation != "tipped" and not truth.held:
            count += 1
    return count


__all__ = ["MujocoCounter", "SimRun", "open_mujoco_backend", "register", "run_dataset"]
