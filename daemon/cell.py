"""Which cell a job runs on: the robot or a simulated cell, built from the config (``open_backend``).

The one builder for ``dishbot run``, the replay and every bench. The hardware backend is assembled in
``daemon.hardware``; a simulated cell in ``daemon.sim_backend``, imported only when one is asked for, so the
robot's process loads no simulator.
"""

from __future__ import annotations

import concurrent.futures

from daemon.backend import Backend, SimOptions
from daemon.clock import RealClock, SessionClock
from daemon.config import Config
from daemon.hardware import open_hardware_backend
from daemon.planners import ProcessMotionPlanner, check_cell_reachable
from planning.arm import ArmModel


async def open_backend(
    config: Config,
    *,
    sim: SimOptions | None = None,
    clock: SessionClock | None = None,
    executor: concurrent.futures.Executor | None = None,
    check_reach: bool = True,
) -> Backend:
    """The cell a job runs on, for ``dishbot run`` and every bench alike: the robot on the ``[hardware]``
    ports, or with ``sim`` the simulated cell (``daemon.sim_backend``, imported only then: the hardware
    backend loads no simulator), moving on ``clock`` (default the wall clock, ``RealClock``).

    Every cell gets the same parts from the config: the cell is refused first when the arm cannot serve it
    (``UsageError``, before any device moves or any simulator starts); the cycle planner plans in the
    configured cell with the configured catalogue and the arm's position correction; the detector looks for
    the configured mug types; a simulated arm starts at ``sim.start_q_rad``. With ``executor`` (a process
    pool) motion planning runs there and the planner starts building in it at once. Call it on the event
    loop that will use the devices. A replay (``check_reach`` False) skips the reach check: the recorded
    daemon made it with the same cell, catalogue and arm when it started."""
    arm = ArmModel.load()
    if check_reach:
        check_cell_reachable(config, arm)
    clock = clock or RealClock()
    if sim is None:
        backend = await open_hardware_backend(config, arm=arm, executor=executor, clock=clock)
    else:
        from daemon.sim_backend import open_sim_backend

        backend = await open_sim_backend(config, sim, arm=arm, clock=clock, executor=executor)
    if isinstance(backend.motion, ProcessMotionPlanner):
        backend.motion.warm_up()
    return backend
