"""What the bus keeps between transactions (the state read's instruction per list of servos, a servo's last
clean reading) never hides a change: a servo that moves reads where it is, one that faults reports it, and a
servo moved to another id or given another model is read afresh. The real bus on dynamixel-sdk talks to the
servo chain simulator over the in-process cable on a simulated clock."""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable

from daemon.clock import SimulatedClock
from drivers.dynamixel import BusConfig, ServoChain
from drivers.dynamixel.bus import DynamixelBus
from drivers.sim.plant import FirstOrderPlant, ServoPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain

Body = Callable[[ServoChainSimulator, ServoChain, FirstOrderPlant, SimulatedClock], Awaitable[None]]


def run(body: Body) -> None:
    clock = SimulatedClock()
    plant = FirstOrderPlant(clock=clock.monotonic)
    run_on(plant, clock, lambda sim, chain: body(sim, chain, plant, clock))


def run_on(
    plant: ServoPlant,
    clock: SimulatedClock,
    body: Callable[[ServoChainSimulator, ServoChain], Awaitable[None]],
) -> None:
    """``body`` with the real bus on a simulated chain of ``plant``'s servos, on ``clock``."""

    async def main() -> None:
        sim = ServoChainSimulator(default_chain(), plant=plant)
        sim.start_in_process(clock)
        try:
            config = BusConfig(sim.device_path, protocol=1)
            async with ServoChain(
                config, default_chain(), clock=clock, read_timeout_s=0.005, open_serial=sim.open_serial
            ) as chain:
                await body(sim, chain)
        finally:
            sim.stop()

    clock.run(main())


def test_a_servo_at_rest_reads_alike_and_one_that_moved_reads_where_it_is() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, plant: FirstOrderPlant, clock: SimulatedClock
    ) -> None:
        first = await chain.call(lambda bus: bus.read_states([1, 2]))
        again = await chain.call(lambda bus: bus.read_states([1, 2]))
        assert again == first  # at rest: the same bytes, the same reading
        plant.set_torque(1, True)
        plant.set_goal(1, first[1].position_rad + 0.5, 2.0)
        await clock.sleep(2.0)
        moved = await chain.call(lambda bus: bus.read_states([1, 2]))
        assert math.isclose(moved[1].position_rad, first[1].position_rad + 0.5, abs_tol=0.01)
        assert moved[2] == first[2]

    run(body)


def test_a_fault_bit_in_an_unchanged_status_is_reported() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, plant: FirstOrderPlant, clock: SimulatedClock
    ) -> None:
        clean = await chain.call(lambda bus: bus.read_states([3], check=False))
        assert clean[3].errors == ()
        sim.overload(3)  # at rest: the same state bytes, with the overload bit in the status
        tripped = await chain.call(lambda bus: bus.read_states([3], check=False))
        assert "overload" in tripped[3].errors
        assert tripped[3].position_rad == clean[3].position_rad

    run(body)


def test_a_servo_given_another_model_is_read_with_that_models_units() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, plant: FirstOrderPlant, clock: SimulatedClock
    ) -> None:
        def twice(bus: DynamixelBus) -> tuple[float, float]:
            as_ax12 = bus.read_states([5])[5].position_rad
            bus.register(5, "MX-28T")  # 4096 ticks a turn where the AX-12A has 1024 over 300 degrees
            return as_ax12, bus.read_states([5])[5].position_rad

        as_ax12, as_mx28 = await chain.call(twice)
        assert as_mx28 != as_ax12

    run(body)


def test_a_servo_moved_to_another_id_is_read_there() -> None:
    async def body(
        sim: ServoChainSimulator, chain: ServoChain, plant: FirstOrderPlant, clock: SimulatedClock
    ) -> None:
        before = await chain.call(lambda bus: bus.read_states([5]))

        def move(bus: DynamixelBus) -> None:
            bus.set_id(5, 9)

        await chain.call(move)
        after = await chain.call(lambda bus: bus.read_states([9]))
        assert after[9].position_rad == before[5].position_rad
        assert after[9].servo_id == 9

    run(body)


class _HeldPlant:
    """A plant whose servos are where the test says (a fake of the physical world)."""

    def __init__(self) -> None:
        self.state: dict[int, tuple[float, float, float]] = {}

    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None:
        pass

    def present(self, servo_id: int) -> tuple[float, float, float]:
        return self.state.get(servo_id, (0.0, 0.0, 0.0))

    def set_torque(self, servo_id: int, on: bool) -> None:
        pass


def test_a_servo_moved_by_less_than_a_tick_reads_alike_and_registers_written_over_read_the_plant_again() -> (
    None
):
    plant = _HeldPlant()
    plant.state[1] = (0.3, 0.2, 0.1)

    async def body(sim: ServoChainSimulator, chain: ServoChain) -> None:
        first = (await chain.call(lambda bus: bus.read_states([1])))[1]
        plant.state[1] = (0.3 + 1e-7, 0.2 + 1e-7, 0.1 + 1e-7)  # well under a tick of each
        assert (await chain.call(lambda bus: bus.read_states([1])))[1] == first
        # Something else writes over the present registers: the next read is the plant's again,
        # though the plant moved by less than a tick since the registers were last synced.
        sim.servo(1).set("present_position", 7)
        sim.servo(1).set("present_speed", 9)
        plant.state[1] = (0.3, 0.2, 0.1)
        assert (await chain.call(lambda bus: bus.read_states([1])))[1] == first
        plant.state[1] = (0.5, 0.2, 0.1)
        moved = (await chain.call(lambda bus: bus.read_states([1])))[1]
        assert math.isclose(moved.position_rad, 0.5, abs_tol=0.01)

    run_on(plant, SimulatedClock(), body)
