"""The grasp verify waits for the FSR reader's debounce instead of racing it, and is bounded (on a simulated
clock: the waits are the job's, in simulated seconds)."""

from __future__ import annotations

import asyncio

from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import Job, StartRequest
from perception import associate
from tests.fakes.job import FakeForce, FakeWorld, make_backend, make_world
from wire.messages import Payload


class DebouncedForce(FakeForce):
    """An FSR reader whose ``holding()`` turns true only ``debounce_s`` after the pads closed on a mug
    (as the real reader's debounce does), or never when ``confirms`` is False."""

    def __init__(
        self, world: FakeWorld, clock: SimulatedClock, *, debounce_s: float, confirms: bool = True
    ) -> None:
        super().__init__(world)
        self.clock = clock
        self.debounce_s = debounce_s
        self.confirms = confirms
        self._held_since: float | None = None
        self.polls = 0

    def holding(self) -> bool:
        self.polls += 1
        if self.w.held is None:
            self._held_since = None
            return False
        if self._held_since is None:
            self._held_since = self.clock.monotonic()
        return self.confirms and self.clock.monotonic() - self._held_since >= self.debounce_s


def _run_job(world: FakeWorld, force: DebouncedForce) -> tuple[Job, float]:
    clock = force.clock
    backend = make_backend(world, clock=clock)
    backend.force = force
    config = load_config(overrides={"planner": {"method": "bh", "time_limit_s": 0.2}})

    def publish(topic: str, payload: Payload) -> None:
        del topic, payload

    job = Job(backend, config, publish, associate)

    async def go() -> float:
        control = asyncio.create_task(job.run())
        try:
            t0 = clock.monotonic()
            await job.command("start", StartRequest())
            async with clock.timeout(20):
                await job.finished.wait()
            return clock.monotonic() - t0
        finally:
            await job.shutdown()
            control.cancel()

    return job, clock.run(go())


def test_a_grasp_confirmed_after_the_debounce_is_verified_not_failed() -> None:
    world = make_world(3)
    job, _ = _run_job(world, DebouncedForce(world, SimulatedClock(), debounce_s=0.03))
    assert job.chart.state == "done"
    assert sorted(world.placed) == ["true0", "true1", "true2"]
    assert job.summary.grasp_failures == 0


def test_a_grasp_the_fsr_never_confirms_fails_after_a_bounded_wait() -> None:
    world = make_world(1)
    force = DebouncedForce(world, SimulatedClock(), debounce_s=0.03, confirms=False)
    job, elapsed = _run_job(world, force)
    assert world.placed == []
    assert (job.summary.grasp_failures, job.summary.failed) == (1, 1)
    assert force.polls > 10  # it waited and polled through the debounce, not read once
    assert elapsed < 2.0  # and gave up within its bound (0.3 s per verify, three attempts)
