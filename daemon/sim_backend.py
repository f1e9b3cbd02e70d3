"""The simulated backends: the kinematic and the MuJoCo cell, each with its counter set up for a job.

``daemon.cell.open_backend`` imports this module only for a simulated cell. Both cells take the same parts
from the config as the robot does (the cycle planner of ``daemon.planners.cycle_planner``, the configured
cell and catalogue), start the arm at ``sim.start_q_rad`` and set their counters up through ``sim.counter``:
a dataset's mugs, or the mugs a ``start`` command lists. They differ where the worlds do. The kinematic
cell's camera sees the world's truth (with noise) and it takes any dataset, switching to the dataset's tray
(the full-size one of datasets 4-6); the MuJoCo cell observes through the rendered depth camera and the
depth detector, and its tray is built into the scene, so a dataset planned on another tray is refused
(``sim.counter.require_cell_tray``: one message, whether at start-up or on a ``start`` command).

Both cells fail as the robot does, for fault files (``replay.faults``), and the same way: their devices are
the same byte-level simulators behind the real drivers (``sim.devices``), with the simulators' own fault
hooks, and each camera is a ``FaultyCamera`` behind the observer's frame checks. Each counter keeps what a
fault acts on (``cell.servo_sim``, ``cell.fsr_sim``, ``camera``).
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from daemon.backend import Backend, EventListener, SetupMug, SimOptions
from daemon.clock import SessionClock
from daemon.config import Config
from daemon.errors import UsageError
from daemon.messages import device_event_payload
from daemon.planners import cycle_planner
from description.cell import CellLayout, Tray
from description.thesis import MugSpec
from drivers.interfaces import Camera
from drivers.sim.camera import FaultyCamera
from perception.interfaces import MugObserver
from perception.observer import cell_observer_factory
from planning.arm import ArmModel
from planning.interfaces import MotionPlanner
from sim.counter import Counter, dataset_counter, listed_counter, require_cell_tray
from sim.kinematic import KinematicCell, MugGeometry, SimMug, start_kinematic_cell

# sim.mujoco is imported when a MuJoCo cell is opened: a kinematic cell (a replay's stand-in) loads no MuJoCo.
if TYPE_CHECKING:
    from sim.mujoco.cell import SimCell

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
    return await open_kinematic_backend(config, options, arm=arm, clock=clock, executor=executor)


def counter_for(
    cell: CellLayout,
    catalogue: Mapping[str, MugSpec],
    *,
    dataset: int | None,
    mugs: Sequence[SetupMug] | None,
) -> Counter:
    """The counter a ``start`` command (or start-up) asks for: the listed mugs, else dataset ``dataset``
    (default 1)."""
    if mugs is not None:
        return listed_counter([(m.mug_id, m.type, m.x_m, m.y_m) for m in mugs], cell, catalogue)
    return dataset_counter(dataset or 1, cell, catalogue)


async def open_kinematic_backend(
    config: Config,
    options: SimOptions,
    *,
    arm: ArmModel,
    clock: SessionClock,
    executor: concurrent.futures.Executor | None = None,
) -> Backend:
    """The kinematic cell (``sim.kinematic``), moving on ``clock``: the real drivers over the device
    simulators, over a world without dynamics; its camera behind the driver's frame checks of ``[camera]``."""
    try:
        first = counter_for(config.cell, config.mug_catalogue(), dataset=options.dataset, mugs=None)
    except ValueError as e:
        raise UsageError(str(e)) from e
    catalogue = config.mug_catalogue()
    tray = config.cell.tray
    cell, closer = await start_kinematic_cell(
        [],
        {n: MugGeometry(m.diameter_mm / 1000.0, m.height_mm / 1000.0) for n, m in catalogue.items()},
        tray_origin_m=tray.origin_m,
        tray_size_m=(tray.size_mm[0] / 1000.0, tray.size_mm[1] / 1000.0),
        clock=clock,
        # As the MuJoCo cell: "holding" at half the grasp threshold.
        holding_threshold_n=config.grasp.force_threshold_n / 2.0,
        fsr_debounce_s=options.fsr_debounce_s,
        detection_noise_m=config.sim.detection_noise_m,
        seed=config.sim.seed if options.seed is None else options.seed,
        catalogue=catalogue,
        frame_limits=config.camera.frames,
        health=config.hardware.health,
        arm=arm,
        q0=np.asarray(config.sim.start_q_rad, dtype=np.float64),
    )
    counter = KinematicCounter(config, cell)
    tray = counter.set_up(first)

    def motion_for(tray: Tray) -> MotionPlanner:
        return cycle_planner(config, tray, arm=arm, executor=executor)

    def on_event(listener: EventListener) -> None:
        cell.on_device_event(lambda e: listener(device_event_payload(e, t=clock.now())))

    return Backend(
        name="sim-kinematic",
        arm=cell.arm,
        gripper=cell.gripper,
        force=cell.force,
        observer=cell.observer,
        motion=motion_for(tray),
        tray=tray,
        counter=counter,
        motion_for=motion_for,
        closer=closer,
        on_event=on_event,
        clock=clock,
        health=cell.health,
    )


class KinematicCounter:
    """Sets the kinematic cell's counter up for a job (``daemon.backend.CounterSetup``): any dataset, on the
    tray it is planned on. ``cell`` is the kinematic cell itself (its device simulators, camera and world,
    for the fault files, tests and benches)."""

    def __init__(self, config: Config, cell: KinematicCell) -> None:
        self._layout = config.cell
        self._catalogue = config.mug_catalogue()
        self.cell = cell
        self.dataset: int | None = None

    @property
    def camera(self) -> FaultyCamera:
        """The camera the observer looks through, whose faults act there."""
        return self.cell.camera

    def set_counter(self, *, dataset: int | None, mugs: Sequence[SetupMug] | None) -> Tray:
        return self.set_up(counter_for(self._layout, self._catalogue, dataset=dataset, mugs=mugs))

    def set_up(self, counter: Counter) -> Tray:
        """Put ``counter``'s mugs out, on its tray."""
        world = self.cell.world
        world.set_mugs(
            [SimMug(m.mug_id, m.spec.name, m.x_m, m.y_m, handle_yaw_rad=m.yaw_rad) for m in counter.mugs]
        )
        world.tray_origin_m = counter.tray.origin_m
        world.tray_size_m = (counter.tray.size_mm[0] / 1000.0, counter.tray.size_mm[1] / 1000.0)
        self.dataset = counter.dataset
        return counter.tray

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
    make_observer = cell_observer_factory(layout, catalogue, clock=clock, limits=config.camera.frames)

    def observer_factory(camera: Camera) -> MugObserver:
        cameras.append(FaultyCamera(camera, clock=clock))
        return make_observer(cameras[-1])

    from sim.mujoco.cell import start_sim_cell

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
            health=config.hardware.health,
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

    def set_counter(self, *, dataset: int | None, mugs: Sequence[SetupMug] | None) -> Tray:
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
