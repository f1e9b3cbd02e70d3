"""What a loading job runs on: the devices, the observer and the motion planner, bundled as a ``Backend``.

The job runner only sees the protocols of ``drivers.interfaces``, ``perception.interfaces`` and
``planning.interfaces``. ``daemon.cell.open_backend`` is the one builder: ``dishbot run`` and every bench get
their cell from it, the robot (``daemon.hardware``) or a simulated cell (``daemon.sim_backend``, imported only
for one, so the hardware backend loads neither the simulated worlds nor MuJoCo). The other concerns a backend
has live beside it: ``daemon.recorded`` wraps a backend so that every input crossing the driver boundary is
also handed to the recording (what a replay needs), ``daemon.planners`` runs the motion planner in a process
pool, ``daemon.messages`` builds the wire messages of what the devices report.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol, TypeVar

import structlog

from daemon.clock import RealClock, SessionClock
from daemon.messages import device_event_payload
from daemon.messages import failure_fields as failure_fields  # replay's tests name it here
from daemon.planners import MotionCalls as MotionCalls  # the replay's planners name it here
from description.cell import Tray
from drivers.dynamixel import DeviceEvent
from drivers.errors import BusLost, DriverError
from drivers.interfaces import (
    ArmDriver,
    DeviceHealth,
    ForceSensor,
    GripperDriver,
)
from drivers.stack import (
    DeviceStack,
)
from perception.interfaces import MugObserver
from planning.interfaces import MotionPlanner
from planning.placement import PlacementPlanner, PlanOptions, PlanResult, Problem

log = structlog.get_logger("daemon.backend")
T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class SetupMug:
    """A mug a simulated counter is set up with (``start`` body ``mugs``)."""

    mug_id: str
    type: str
    x_m: float
    y_m: float


class CounterSetup(Protocol):
    """Only a simulated cell can put mugs on its counter; it returns the tray the job should fill."""

    def set_counter(self, *, dataset: int | None, mugs: Sequence[SetupMug] | None) -> Tray: ...

    def scene(self) -> dict[str, object]: ...


EventListener = Callable[[Mapping[str, object]], None]
PlanPlacement = Callable[[PlacementPlanner, Problem, PlanOptions], Awaitable[PlanResult]]
# How a backend has placement planned: given the job's planner, the problem, the options and the job's own
# way of running a planner off the event loop.
PlacementRunner = Callable[[PlacementPlanner, Problem, PlanOptions, PlanPlacement], Awaitable[PlanResult]]


class DeviceEvents:
    """Fans driver events out to the listeners registered through ``Backend.on_event``."""

    def __init__(self, clock: SessionClock) -> None:
        self._clock = clock
        self._listeners: list[EventListener] = []

    def add(self, listener: EventListener) -> None:
        self._listeners.append(listener)

    def __call__(self, event: DeviceEvent) -> None:
        payload = device_event_payload(event, t=self._clock.now())
        for listener in self._listeners:
            listener(payload)


async def _nothing() -> None:
    return None


@dataclass(slots=True)
class Backend:
    """The bundle a job runs on. ``tray`` may change when a simulated counter is set up for a new job."""

    name: str
    arm: ArmDriver
    gripper: GripperDriver
    force: ForceSensor
    observer: MugObserver
    motion: MotionPlanner
    tray: Tray
    counter: CounterSetup | None = None
    closer: Callable[[], Awaitable[None]] = field(default=_nothing)
    # The motion planner for another tray (a simulated counter set up with a different tray).
    motion_for: Callable[[Tray], MotionPlanner] | None = None
    # Devices that report events of their own (tray collisions in simulation) call the listener given here,
    # possibly from another thread.
    on_event: Callable[[EventListener], None] | None = None
    # The Dynamixel/FSR device stack when the backend runs one (hardware): bus counters, diagnostics.
    devices: DeviceStack | None = None
    # The devices' health, polled by the daemon, asked before a start and cleared on reset; None when the
    # backend has no devices of its own to check (the kinematic cell).
    health: DeviceHealth | None = None
    # The one clock everything of this backend and the job on it reads and waits on: the wall clock on the
    # robot, the simulated cell's clock in simulation.
    clock: SessionClock = field(default_factory=RealClock)
    # None: the job plans placements itself (in the planning process); a replay serves the recorded plans.
    placement: PlacementRunner | None = None

    def scene(self) -> dict[str, object]:
        """The initial scene for the recording's session header."""
        base: dict[str, object] = {
            "backend": self.name,
            "tray": {"origin_m": list(self.tray.origin_m), "size_mm": list(self.tray.size_mm)},
        }
        if self.counter is not None:
            base.update(self.counter.scene())
        return base

    async def close(self) -> None:
        """Release the devices. One that cannot be reached now (a silent servo, a pulled adapter: the arm
        cannot be relaxed) is logged, not raised: the others are released all the same, and the daemon's
        shutdown goes on to its end."""
        try:
            await self.closer()
        except (DriverError, BusLost) as e:
            log.error("device_close_failed", error=f"{type(e).__name__}: {e}")


@dataclass(frozen=True, slots=True)
class SimOptions:
    """The simulated cell ``dishbot run --sim`` and the benches ask for. ``world`` is ``kinematic`` (the fast
    placeholder) or ``mujoco`` (physics behind the real drivers); None takes ``sim.world``. ``transport``
    (MuJoCo cell; default ``sim.transport``) is ``inprocess`` (the drivers' bytes reach the simulators in
    this process, on simulated time) or ``pty`` (over pseudo-terminals, on the wall clock). How fast
    simulated time runs is the clock's business, not the cell's. ``dataset`` is set out on the counter;
    ``seed`` (default ``sim.seed``) seeds the detection noise; ``fsr_debounce_s`` is how long the MuJoCo
    cell's FSR reader waits before it believes a crossing (the reader's own default)."""

    world: str | None = None
    dataset: int = 1
    transport: str | None = None
    seed: int | None = None
    fsr_debounce_s: float = 0.03
