"""The simulated backends: the kinematic and the MuJoCo cell, each with its counter set up for a job.

``daemon.cell.open_backend`` imports this module only for a simulated cell. Both cells take the same parts
from the config as the robot does (the cycle planner of ``daemon.backend.cycle_planner``, the configured
cell and catalogue), start the arm at ``sim.start_q_rad`` and set their counters up through ``sim.counter``:
a dataset's mugs, or the mugs a ``start`` command lists. They differ where the worlds do. The kinematic
cell observes through the world's truth with noise and takes any dataset, switching to the dataset's tray
(the full-size one of datasets 4-6); the MuJoCo cell observes through the rendered depth camera and the
depth detector, and its tray is built into the scene, so a dataset planned on another tray is refused
(``sim.counter.require_cell_tray``: one message, whether at start-up or on a ``start`` command).

Both cells can fail as the robot does, for fault files (``replay.faults``): the kinematic cell's
devices carry their faults (``sim.kinematic.faults``) and its observer the camera's (``FaultyObserver``); the
MuJoCo cell's device simulators have their own fault hooks and its camera is a ``FaultyCamera``. Each
counter keeps what a fault acts on (``KinematicCounter.observer``, ``MujocoCounter.camera``).
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Mapping, Sequence

import numpy as np

from daemon.backend import (
    Backend,
    CounterMug,
    EventListener,
    SimOptions,
    cycle_planner,
    device_event_payload,
    frame_limits,
    health_limits,
)
from daemon.clock import SessionClock
from daemon.config import Config
from daemon.errors import UsageError
from description.cell import CellLayout, Tray
from description.thesis import MugSpec
from drivers.interfaces import Camera
from drivers.sim.camera import FaultyCamera
from perception.interfaces import Detection, MugObserver
from perception.observer import cell_observer_factory
from planning.arm import ArmModel
from planning.interfaces import MotionPlanner
from sim.counter import Counter, dataset_counter, listed_counter, require_cell_tray
from sim.kinematic import KinematicCell, MugGeometry, SimMug, open_kinematic_cell
from sim.kinematic.faults import KinematicHealth
from sim.mujoco.cell import SimCell, start_sim_cell
from sim.truth import FaultyObserver, TruthObserver

WORLDS = ("kinematic", "mujoco")


async def open_sim_backend(
    config: Config,
    options: SimOptions,
    *,
    arm: ArmModel,
    clock: SessionClock,
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The simulated cell ``options`` asks for, with its dataset on the counter, moving on ``clock``;
    ``UsageError`` for a world, transport or dataset it cannot run."""
    world = options.world or config.sim.world
    if world == "mujoco":
        return await open_mujoco_backend(config, options, arm=arm, clock=clock, executor=executor)
    if world != "kinematic":
        raise UsageError(f"--world {world}: choose {' or '.join(WORLDS)}")
    return open_kinematic_backend(config, options, arm=arm, clock=clock, executor=executor)


def counter_for(
    cell: CellLayout,
    catalogue: Mapping[str, MugSpec],
    *,
    dataset: int | None,
    mugs: Sequence[CounterMug] | None,
) -> Counter:
    """The counter a ``start`` command (or start-up) asks for: the listed mugs, else dataset ``dataset``
    (default 1)."""
    if mugs is not None:
        return listed_counter([(m.mug_id, m.type, m.x_m, m.y_m) for m in mugs], cell, catalogue)
    return dataset_counter(dataset or 1, cell, catalogue)


def open_kinematic_backend(
    config: Config,
    options: SimOptions,
    *,
    arm: ArmModel,
    clock: SessionClock,
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The kinematic placeholder cell (``sim.kinematic``), moving on ``clock``."""
    seed = config.sim.seed if options.seed is None else options.seed
    counter = KinematicCounter(config, arm, clock=clock)
    try:
        tray = counter.set_counter(dataset=options.dataset, mugs=None)
    except ValueError as e:
        raise UsageError(str(e)) from e
    observer = FaultyObserver(
        TruthObserver(counter.visible_mugs, clock=clock, noise_m=config.sim.detection_noise_m, seed=seed),
        clock=clock,
    )
    counter.observer = observer

    def motion_for(tray: Tray) -> MotionPlanner:
        return cycle_planner(config, tray, arm=arm, executor=executor)

    def on_event(listener: EventListener) -> None:
        counter.cell.world.faults.on_event(lambda e: listener(device_event_payload(e, t=clock.now())))

    return Backend(
        name="sim-kinematic",
        arm=counter.cell.arm,
        gripper=counter.cell.gripper,
        force=counter.cell.force,
        observer=observer,
        motion=motion_for(tray),
        tray=tray,
        counter=counter,
        motion_for=motion_for,
        on_event=on_event,
        clock=clock,
        health=KinematicHealth(counter.cell.world.faults, poll_period_s=config.hardware.health.poll_period_s),
    )


class KinematicCounter:
    """Sets the kinematic cell's counter up for a job (``daemon.backend.CounterSetup``): any dataset, on the
    tray it is planned on."""

    def __init__(self, config: Config, arm: ArmModel, *, clock: SessionClock) -> None:
        self._layout = config.cell
        self._catalogue = config.mug_catalogue()
        tray = config.cell.tray
        self.cell: KinematicCell = open_kinematic_cell(
            [],
            {
                n: MugGeometry(m.diameter_mm / 1000.0, m.height_mm / 1000.0)
                for n, m in self._catalogue.items()
            },
            tray_origin_m=tray.origin_m,
            tray_size_m=(tray.size_mm[0] / 1000.0, tray.size_mm[1] / 1000.0),
            clock=clock,
            joint_speed_rad_s=config.sim.joint_speed_rad_s,
            holding_threshold_n=config.grasp.force_threshold_n / 2.0,
            arm=arm,
            q0=np.asarray(config.sim.start_q_rad, dtype=np.float64),
        )
        self.dataset: int | None = None
        self.observer: FaultyObserver | None = None  # the cell's observer, whose camera faults act there

    def set_counter(self, *, dataset: int | None, mugs: Sequence[CounterMug] | None) -> Tray:
        counter = counter_for(self._layout, self._catalogue, dataset=dataset, mugs=mugs)
        world = self.cell.world
        world.set_mugs(
            [SimMug(m.mug_id, m.spec.name, m.x_m, m.y_m, handle_yaw_rad=m.yaw_rad) for m in counter.mugs]
        )
        world.tray_origin_m = counter.tray.origin_m
        world.tray_size_m = (counter.tray.size_mm[0] / 1000.0, counter.tray.size_mm[1] / 1000.0)
        self.dataset = counter.dataset
        return counter.tray

    def visible_mugs(self) -> list[Detection]:
        return [
            Detection(m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, 1.0)
            for m in self.cell.world.mugs.values()
            if m.where == "counter"
        ]

    def scene(self) -> dict[str, object]:
        return {**self.cell.world.scene(), "dataset": self.dataset}


async def open_mujoco_backend(
    config: Config,
    options: SimOptions,
    *,
    arm: ArmModel,
    clock: SessionClock,
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The MuJoCo cell (``sim.mujoco``): real drivers over simulated servos and FSR, the rendered depth
    camera and the depth detector on the configured catalogue, as on the robot. In-process on a simulated
    ``clock`` it runs as fast as the machine allows (or at the clock's speed); on pseudo-terminals
    (``options.transport`` ``"pty"``) it runs on the wall clock."""
    layout = config.cell
    catalogue = config.mug_catalogue()
    try:
        first = mujoco_counter(config, options.dataset)
    except ValueError as e:
        raise UsageError(str(e)) from e
    cameras: list[FaultyCamera] = []
    make_observer = cell_observer_factory(layout, catalogue, clock=clock, limits=frame_limits(config))

    def observer_factory(camera: Camera) -> MugObserver:
        cameras.append(FaultyCamera(camera, clock=clock))
        return make_observer(cameras[-1])

    try:
        cell, closer = await start_sim_cell(
            layout,
            first.mugs,
            clock=clock,
            transport=options.transport or config.sim.transport,
            seed=config.sim.seed if options.seed is None else options.seed,
            start_pose_rad=config.sim.start_q_rad,
            # As the kinematic cell: "holding" at half the grasp threshold.
            holding_threshold_n=config.grasp.force_threshold_n / 2.0,
            fsr_debounce_s=options.fsr_debounce_s,
            observer_factory=observer_factory,
            health=health_limits(config),
        )
    except ValueError as e:  # a transport the clock cannot drive
        raise UsageError(str(e)) from e
    counter = MujocoCounter(cell, layout, catalogue, dataset=first.dataset, camera=cameras[0])

    def on_event(listener: EventListener) -> None:
        cell.on_collision(
            lambda c: listener({**c.to_event(), "kind": "tray_collision", "t_sim": c.t, "t": clock.now()})
        )
        cell.on_device_event(lambda e: listener(device_event_payload(e, t=clock.now())))

    return Backend(
        name="sim-mujoco",
        arm=cell.arm,
        gripper=cell.gripper,
        force=cell.force,
        observer=cell.observer,
        motion=cycle_planner(config, layout.tray, arm=arm, executor=executor),
        tray=layout.tray,
        counter=counter,
        closer=closer,
        on_event=on_event,
        health=cell.health,
        clock=clock,
    )


def mujoco_counter(config: Config, dataset: int) -> Counter:
    """Dataset ``dataset``'s counter in the MuJoCo cell; ValueError with the one message when the dataset is
    planned on another tray than the cell's (``sim.counter.require_cell_tray``)."""
    counter = dataset_counter(dataset, config.cell, config.mug_catalogue())
    require_cell_tray(counter, config.cell)
    return counter


class MujocoCounter:
    """Sets the MuJoCo cell's counter up for a job (``daemon.backend.CounterSetup``); ``cell`` is the
    simulated cell itself (its world's ground truth and tray collisions, for tests and benches), ``camera``
    the one its observer looks through."""

    def __init__(
        self,
        cell: SimCell,
        layout: CellLayout,
        catalogue: Mapping[str, MugSpec],
        *,
        dataset: int | None,
        camera: FaultyCamera | None = None,
    ) -> None:
        self.cell = cell
        self.camera = camera  # the camera the observer looks through, whose faults act there
        self._layout = layout
        self._catalogue = dict(catalogue)
        self.dataset = dataset

    def set_counter(self, *, dataset: int | None, mugs: Sequence[CounterMug] | None) -> Tray:
        counter = counter_for(self._layout, self._catalogue, dataset=dataset, mugs=mugs)
        require_cell_tray(counter, self._layout)
        self.cell.set_counter(counter.mugs)
        self.dataset = counter.dataset
        return counter.tray

    def scene(self) -> dict[str, object]:
        return {**self.cell.scene(), "dataset": self.dataset}


def mujoco_cell(backend: Backend) -> SimCell:
    """The simulated cell behind a MuJoCo backend (its world's ground truth, for the benches)."""
    if not isinstance(backend.counter, MujocoCounter):
        raise TypeError(f"backend {backend.name} is not the MuJoCo cell")
    return backend.counter.cell
