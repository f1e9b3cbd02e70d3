"""Stand-ins for the physical world in driver tests (the devices themselves speak the real wire protocol),
and the two ways tests reach the simulated devices: in-process on a simulated clock (fast, deterministic:
most tests), or on pseudo-terminals on the wall clock (the transport the robot's OS path has)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import threading
from collections.abc import Callable, Coroutine, Iterable, Iterator
from typing import Any, Final, ParamSpec, TypeVar

import numpy as np

from daemon.clock import RealClock, SessionClock, SimulatedClock
from drivers.dynamixel import BusConfig, DynamixelBus
from drivers.dynamixel.bus import EventSink
from drivers.interfaces import Clock, ForceReading, RGBDFrame
from drivers.serial_port import OpenSerial, open_pyserial
from drivers.sim.device import SimulatedDevice
from drivers.sim.plant import FirstOrderPlant, ServoPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain

P = ParamSpec("P")
T = TypeVar("T")
D = TypeVar("D", bound=SimulatedDevice)

TRANSPORTS: Final = ("inprocess", "pty")


def clock_for(transport: str) -> SessionClock:
    """Simulated time for the in-process transport, the wall clock for pseudo-terminals."""
    return SimulatedClock() if transport == "inprocess" else RealClock()


def run_on(transport: str, body: Callable[[SessionClock], Coroutine[Any, Any, T]]) -> T:
    """Run ``body(clock)`` on the clock of ``transport``'s event loop."""
    clock = clock_for(transport)
    return clock.run(body(clock))


@contextlib.contextmanager
def serving(device: D, transport: str, clock: Clock) -> Iterator[D]:
    """``device`` on ``transport`` (in-process: on ``clock``, from a coroutine) until the block ends."""
    if transport == "pty":
        device.start()
    else:
        device.start_in_process(clock)
    try:
        yield device
    finally:
        device.stop()


@contextlib.contextmanager
def inprocess_chain(
    *, read_timeout_s: float, plant: ServoPlant | None = None, on_event: EventSink | None = None
) -> Iterator[tuple[ServoChainSimulator, DynamixelBus]]:
    """The default servo chain (on ``plant``) simulated in-process on the wall clock, and an open bus that
    has verified it: where a bus test starts."""
    clock = RealClock()
    with serving(ServoChainSimulator(default_chain(), plant=plant), "inprocess", clock) as sim:
        bus = DynamixelBus(
            BusConfig(sim.device_path),
            clock=clock,
            on_event=on_event,
            read_timeout_s=read_timeout_s,
            open_serial=sim.open_serial,
        )
        with bus:
            bus.verify(default_chain())
            yield sim, bus


def opener(device: SimulatedDevice) -> OpenSerial:
    """How a driver opens ``device.device_path``: the in-process cable's opener, or pyserial on the pty."""
    return device.open_serial or open_pyserial


# Status timeout for tests: long enough that a loaded 2-core CI machine never turns a slow answer into a
# retry, so retry counters stay exact; it only costs time when a test drops packets on purpose.
PATIENT_S = 0.2


def async_test(fn: Callable[P, Coroutine[Any, Any, None]]) -> Callable[P, None]:
    """Run an async test body on a fresh event loop (the suite has no asyncio plugin)."""

    @functools.wraps(fn)
    def run(*args: P.args, **kwargs: P.kwargs) -> None:
        asyncio.run(fn(*args, **kwargs))

    return run


class MugBetweenPads(FirstOrderPlant):
    """The physical world of a grasp: a mug stops the gripper's pads at its diameter and pushes back.

    The force on the pad grows with how far the servo's goal lies beyond the contact angle, as a stiff mug
    compressing the FSR would make it; without a mug the pads close freely.
    """

    def __init__(
        self,
        gripper_id: int,
        contact_rad: float | None,
        *,
        clock: Callable[[], float],
        stiffness_n_per_rad: float = 60.0,
    ) -> None:
        super().__init__(clock=clock, tau_s=0.02)
        self.gripper_id = gripper_id
        self.contact_rad = contact_rad
        self.stiffness = stiffness_n_per_rad
        self._goal_rad = 0.0
        self._mug_lock = threading.Lock()

    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None:
        if servo_id == self.gripper_id:
            with self._mug_lock:
                self._goal_rad = position_rad
            if self.contact_rad is not None:
                position_rad = min(position_rad, self.contact_rad)
        super().set_goal(servo_id, position_rad, speed_rad_s)

    def force_n(self) -> float:
        with self._mug_lock:
            if self.contact_rad is None:
                return 0.0
            return max(0.0, (self._goal_rad - self.contact_rad) * self.stiffness)


class PlantForceSensor:
    """A ForceSensor reading the stand-in world directly (the FSR wire path has its own tests)."""

    def __init__(self, plant: MugBetweenPads, clock: Clock, threshold_n: float = 1.0) -> None:
        self.plant = plant
        self.clock = clock
        self.threshold_n = threshold_n
        self.seq = 0

    def latest(self) -> ForceReading | None:
        self.seq += 1
        return ForceReading(self.clock.monotonic(), self.plant.force_n(), 0, self.seq)

    def holding(self) -> bool:
        return self.plant.force_n() >= self.threshold_n


CAMERA_FAULTS: Final = ("ok", "hang", "stale", "nan", "shape")


class ScriptedCamera:
    """A depth camera seeing ``frame`` (stamped with the clock's time at each capture), whose captures go
    by ``script``, one entry each, then ``then`` for ever: ``ok``; ``hang`` (the capture never returns, as
    a camera whose USB link stalled); ``stale`` (a frame stamped ``stale_s`` ago, as a driver handing out
    an old buffer); ``nan`` (half the depth NaN); ``shape`` (a half-size depth image)."""

    def __init__(
        self,
        frame: RGBDFrame,
        clock: Clock,
        script: Iterable[str] = (),
        *,
        then: str = "ok",
        stale_s: float = 600.0,
    ) -> None:
        self._frame = frame
        self._clock = clock
        self._script = list(script)
        self._then = then
        self._stale_s = stale_s
        self.captures: list[str] = []
        for fault in (*self._script, then):
            if fault not in CAMERA_FAULTS:
                raise ValueError(f"camera fault {fault!r}: one of {', '.join(CAMERA_FAULTS)}")

    async def capture(self) -> RGBDFrame:
        fault = self._script.pop(0) if self._script else self._then
        self.captures.append(fault)
        frame = dataclasses.replace(self._frame, t=self._clock.monotonic())
        if fault == "hang":
            await asyncio.Event().wait()
        if fault == "stale":
            return dataclasses.replace(frame, t=frame.t - self._stale_s)
        if fault == "nan":
            depth = frame.depth_m.copy()
            depth[: depth.shape[0] // 2] = np.nan
            return dataclasses.replace(frame, depth_m=depth)
        if fault == "shape":
            return dataclasses.replace(frame, depth_m=np.ascontiguousarray(frame.depth_m[::2, ::2]))
        return frame
