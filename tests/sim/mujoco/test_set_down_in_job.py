"""Where the daemon's job leaves a flipped mug in the MuJoCo cell: on its slot, within a few millimetres.

The job runs on the real drivers and the cell's physics, as ``dishbot bench sim`` does. A mug leans in the
side grasp after each carry (it swings about the pads) and straightens only slowly; let go while it still
leant, its brim landed 5-8 mm out along the approach (dataset 3, seed 1: a small mug then touched its
neighbour, whose plan kept 10 mm). The slow last stretch of the set-downs lets it hang straight first."""

from __future__ import annotations

import asyncio
import math

import pytest

from daemon.backend import SetupMug, SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job, StartRequest
from daemon.job.runner import cancel_and_wait
from daemon.sim_backend import mujoco_cell
from perception import associate
from wire.messages import MugPlacedEvent, Payload

# Dataset 3's small mugs m2 and m3 where its counter sets them out (their errors were 8 and 5 mm).
_MUGS = (SetupMug("m2", "small", 0.2195, 0.4155), SetupMug("m3", "small", 0.0635, 0.4155))


async def _job(mugs: tuple[SetupMug, ...], clock: SimulatedClock) -> tuple[dict[str, float], list[object]]:
    """Run one loading job of ``mugs``; each placed mug's distance from its slot (m), and the collisions."""
    config = load_config()
    backend = await open_backend(config, sim=SimOptions(world="mujoco", dataset=3, seed=1), clock=clock)
    cell = mujoco_cell(backend)
    collisions: list[object] = []
    cell.on_collision(collisions.append)
    slots: dict[str, tuple[float, float]] = {}

    def publish(key: str, payload: Payload) -> None:
        if isinstance(payload, MugPlacedEvent):
            slots[payload.mug_id] = (payload.x_m, payload.y_m)

    job = Job(backend, config, publish, associate)
    control = asyncio.create_task(job.run())
    try:
        await job.command("start", StartRequest(mugs=mugs))
        async with clock.timeout(600.0):
            await job.finished.wait()
        await clock.sleep(1.0)  # let the last mug come to rest
        # The job names mugs as it detects them: each slot's mug is the one nearest it.
        truths = cell.world.mug_truths().values()
        errors = {}
        for mug, xy in slots.items():
            nearest = min(truths, key=lambda t: math.dist(t.position_m[:2], xy))
            assert nearest.orientation == "inverted", mug
            errors[mug] = math.dist(nearest.position_m[:2], xy)
        return errors, collisions
    finally:
        await job.shutdown()
        await cancel_and_wait(control)
        await backend.close()


@pytest.mark.slow
def test_the_job_sets_flipped_small_mugs_down_within_3_mm_of_their_slots() -> None:
    clock = SimulatedClock()
    errors, collisions = clock.run(_job(_MUGS, clock))
    print({m: round(e * 1000.0, 1) for m, e in errors.items()})
    assert len(errors) == len(_MUGS)
    assert max(errors.values()) < 0.003
    assert collisions == []
