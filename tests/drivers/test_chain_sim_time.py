"""The servo chain on an in-process cable and a simulated clock (``ServoChain(inline=True)``, as the
simulated cells run it): a transaction answered at once takes no simulated time; one that waits on a
servo (a lost or garbled answer) waits in simulated time, as the robot's bus waits in real time, so a
servo silent for a moment is bridged by the retries and one silent for good faults once they are spent.
The real bus on dynamixel-sdk talks to the servo chain simulator; nothing depends on the machine's speed."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import pytest

from daemon.clock import SimulatedClock
from drivers.dynamixel import BusConfig, BusTimeout, DeviceEvent, ServoChain
from drivers.dynamixel.bus import DynamixelBus, ServoReading
from drivers.sim.plant import FirstOrderPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain

IDS = [1, 2, 3, 4, 5, 6]
TIMEOUT_S = 0.02  # the bus's status timeout; an exchange waits that plus 2 ms per expected answer
RETRIES = 3
Body = Callable[[SimulatedClock, ServoChainSimulator, ServoChain, list[DeviceEvent]], Awaitable[None]]


def run(body: Body) -> None:
    """``body(clock, sim, chain, events)`` on an inline chain over the in-process simulator."""
    clock = SimulatedClock()
    events: list[DeviceEvent] = []

    async def main() -> None:
        sim = ServoChainSimulator(default_chain(), plant=FirstOrderPlant(clock=clock.monotonic))
        sim.start_in_process(clock)
        try:
            chain = ServoChain(
                BusConfig(sim.device_path),
                default_chain(),
                clock=clock,
                retries=RETRIES,
                read_timeout_s=TIMEOUT_S,
                on_event=events.append,
                open_serial=sim.open_serial,
                inline=True,
            )
            async with chain:
                await body(clock, sim, chain, events)
        finally:
            sim.stop()

    clock.run(main())


def read_all(bus: DynamixelBus) -> dict[int, ServoReading]:
    return bus.read_states(IDS)


def later(clock: SimulatedClock, delay_s: float, action: Callable[[], None]) -> None:
    asyncio.get_running_loop().call_at(clock.monotonic() + delay_s, action)


def test_a_transaction_answered_at_once_takes_no_simulated_time() -> None:
    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        t0 = clock.monotonic()
        for _ in range(10):
            assert sorted(await chain.call(read_all)) == IDS
        assert clock.monotonic() == t0
        assert all(c.retries == 0 and c.timeouts == 0 for c in chain.counters().values())

    run(body)


def test_a_servo_silent_for_10_ms_is_bridged_by_one_retry_a_status_timeout_later() -> None:
    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        sim.silence(4)
        later(clock, 0.010, lambda: sim.silence(4, on=False))
        t0 = clock.monotonic()
        readings = await chain.call(read_all)
        assert sorted(readings) == IDS
        # The daisy chain stalled at servo 4: the first bulk read waited out its timeout (6 answers
        # expected), the retry of 4-6 came after the silence and was answered at once.
        assert clock.monotonic() - t0 == pytest.approx(TIMEOUT_S + 6 * 0.002)
        counters = chain.counters()
        assert [counters[i].retries for i in IDS] == [0, 0, 0, 1, 1, 1]
        assert [e.kind for e in events] == []

    run(body)


def test_a_servo_silent_for_good_faults_after_every_retry_each_a_timeout_apart() -> None:
    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        sim.silence(4)
        t0 = clock.monotonic()
        with pytest.raises(BusTimeout) as raised:
            await chain.call(read_all)
        assert str(raised.value) == (
            f"servo(s) 4 did not answer on {sim.device_path} after {1 + RETRIES} tries; check the cable and "
            "power of the chain"
        )
        # 4 tries (the first of 6 answers, the retries of 4-6), then the blame: a ping of 4 goes unanswered,
        # 5 and 6 answer theirs at once.
        waited = (TIMEOUT_S + 6 * 0.002) + RETRIES * (TIMEOUT_S + 3 * 0.002) + (TIMEOUT_S + 0.002)
        assert clock.monotonic() - t0 == pytest.approx(waited)
        assert [(e.kind, e.detail["servo"], e.detail["reason"]) for e in events] == [
            ("servo_fault", 4, "no_status")
        ]

    run(body)


def test_one_lost_answer_costs_one_status_timeout() -> None:
    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        sim.drop(2)
        t0 = clock.monotonic()
        assert sorted(await chain.call(read_all)) == IDS
        assert clock.monotonic() - t0 == pytest.approx(TIMEOUT_S + 6 * 0.002)
        t1 = clock.monotonic()
        await chain.call(read_all)
        assert clock.monotonic() == t1  # answered at once again

    run(body)


def test_transactions_keep_their_order_while_one_waits_on_a_silent_servo() -> None:
    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        done: list[tuple[str, float]] = []

        async def read(name: str, ids: list[int]) -> None:
            await chain.call(lambda bus: bus.read_states(ids))
            done.append((name, clock.monotonic()))

        sim.silence(4)
        later(clock, 0.010, lambda: sim.silence(4, on=False))
        t0 = clock.monotonic()
        await asyncio.gather(read("arm", [1, 2, 3, 4, 5]), read("gripper", [6]), read("arm again", [1, 2]))
        waited = TIMEOUT_S + 5 * 0.002
        assert [name for name, _ in done] == ["arm", "gripper", "arm again"]
        assert [t - t0 for _, t in done] == pytest.approx([waited] * 3)

    run(body)


def test_a_caller_cancelled_while_the_bus_waits_leaves_the_bus_to_the_next_one() -> None:
    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        sim.silence(4)
        waiting = asyncio.get_running_loop().create_task(chain.call(read_all))
        await clock.sleep(0.005)  # inside the first status timeout
        waiting.cancel()
        with pytest.raises(asyncio.CancelledError):
            await waiting
        sim.silence(4, on=False)
        t0 = clock.monotonic()
        assert sorted(await chain.call(read_all)) == IDS
        assert clock.monotonic() == t0

    run(body)


def test_an_idle_servo_answers_what_changed_since_its_last_answer_at_once() -> None:
    """The simulator reuses an idle servo's status packet only while nothing changed: a fault hook, a write
    or the plant moving shows in the very next answer."""

    async def body(
        clock: SimulatedClock, sim: ServoChainSimulator, chain: ServoChain, events: list[DeviceEvent]
    ) -> None:
        first = await chain.call(read_all)
        assert await chain.call(read_all) == first  # at rest, nothing changed: the same readings
        sim.set_present_voltage(3, 11.1)
        again = await chain.call(read_all)
        assert again[3].voltage_v == 11.1
        assert {i: r for i, r in again.items() if i != 3} == {i: r for i, r in first.items() if i != 3}
        sim.overheat(5)
        hot = await chain.call(lambda bus: bus.read_states([5], check=False))
        assert "overheating" in hot[5].errors
        await chain.call(lambda bus: bus.write_register(2, "torque_enable", 1))
        await chain.call(lambda bus: bus.write_goals({2: (0.3, 1.0)}))
        await clock.sleep(0.05)
        moved = await chain.call(lambda bus: bus.read_states([2]))
        assert moved[2].position_rad > first[2].position_rad

    run(body)
