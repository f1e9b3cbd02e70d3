"""A host that is scheduled late must not call a servo silent whose answer has already arrived.

On a loaded machine the bus's thread can lose the CPU between sending an instruction and looking for the
answer. If it comes back after the answer's deadline, the answer may still be waiting in the port's
buffer: the bus reads what is there before it gives up, and counts no timeout."""

from __future__ import annotations

import itertools

from daemon.clock import RealClock
from drivers.dynamixel import BusConfig, DynamixelBus
from drivers.dynamixel.bus import WallWaits
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from tests.fakes.devices import serving


class LateHost(WallWaits):
    """Wall-clock waits whose every look at the clock finds another second gone: the bus's thread misses
    each deadline it sets. The answer of the in-process simulator is in the buffer as soon as the
    instruction is written."""

    def __init__(self) -> None:
        self._late = itertools.count()

    def now(self) -> float:
        return super().now() + next(self._late)


def test_an_answer_waiting_in_the_buffer_after_the_deadline_is_read_not_timed_out() -> None:
    clock = RealClock()
    with serving(ServoChainSimulator(default_chain()), "inprocess", clock) as sim:
        bus = DynamixelBus(
            BusConfig(sim.device_path), clock=clock, read_timeout_s=0.01, open_serial=sim.open_serial
        )
        with bus:
            bus.verify(default_chain())
            bus.waits = LateHost()
            assert bus.ping(1) is not None
            assert bus.read_register(1, "present_position") == bus.read_register(1, "present_position")
            readings = bus.read_states([1, 2, 3])
            assert sorted(readings) == [1, 2, 3]
            assert all(bus.counters[i].timeouts == 0 and bus.counters[i].retries == 0 for i in (1, 2, 3))
