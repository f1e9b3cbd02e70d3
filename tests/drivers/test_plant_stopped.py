"""Servos whose physical side is gone (the simulated world died) fall silent, as servos without power: the
host's bus times out and says which servos did not answer; the simulator says why once."""

from __future__ import annotations

import pytest
from structlog.testing import capture_logs

from daemon.clock import RealClock
from drivers.dynamixel import BusTimeout
from drivers.sim.plant import FirstOrderPlant, PlantStopped
from tests.fakes.devices import inprocess_chain


class DyingPlant(FirstOrderPlant):
    """A first-order plant whose simulation dies when told to."""

    def __init__(self, clock: RealClock) -> None:
        super().__init__(clock=clock.monotonic)
        self.dead = False

    def present(self, servo_id: int) -> tuple[float, float, float]:
        if self.dead:
            raise PlantStopped("the physics died: the simulation diverged by t=20.014 s")
        return super().present(servo_id)


def test_servos_whose_plant_died_answer_nothing_and_the_simulator_says_why_once() -> None:
    plant = DyingPlant(RealClock())
    with inprocess_chain(read_timeout_s=0.005, plant=plant) as (_, bus):
        assert sorted(bus.read_states([1, 2, 3])) == [1, 2, 3]
        plant.dead = True
        with capture_logs() as logs:
            with pytest.raises(BusTimeout, match=r"^servo\(s\) 1, 2, 3 did not answer"):
                bus.read_states([1, 2, 3])
            assert bus.ping(1) is None  # not even a ping, once the plant is gone
        silent = [e for e in logs if e["event"] == "sim_servos_silent"]
        assert [e["reason"] for e in silent] == ["the physics died: the simulation diverged by t=20.014 s"]
        assert not [e for e in logs if e["event"] == "sim_packet_failed"]
