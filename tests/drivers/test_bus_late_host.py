"""A host that is scheduled late must not call a servo silent whose answer has already arrived.

On a loaded machine the bus's thread can lose the CPU between sending an instruction and looking for the
answer. If it comes back after the answer's deadline, the answer may still be waiting in the port's
buffer: the bus reads what is there before it gives up, and counts no timeout."""

from __future__ import annotations

import itertools

from drivers.dynamixel.bus import WallWaits
from tests.fakes.devices import inprocess_chain


class LateHost(WallWaits):
    """Wall-clock waits whose every look at the clock finds another second gone: the bus's thread misses
    each deadline it sets. The answer of the in-process simulator is in the buffer as soon as the
    instruction is written."""

    def __init__(self) -> None:
        self._late = itertools.count()

    def now(self) -> float:
        return super().now() + next(self._late)


def test_an_answer_waiting_in_the_buffer_after_the_deadline_is_read_not_timed_out() -> None:
    with inprocess_chain(read_timeout_s=0.01) as (_, bus):
        bus.waits = LateHost()
        assert bus.ping(1) is not None
        assert bus.read_register(1, "present_position") == bus.read_register(1, "present_position")
        readings = bus.read_states([1, 2, 3])
        assert sorted(readings) == [1, 2, 3]
        assert all(bus.counters[i].timeouts == 0 and bus.counters[i].retries == 0 for i in (1, 2, 3))
