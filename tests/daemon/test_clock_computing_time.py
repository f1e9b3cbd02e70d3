"""Executor work that takes simulated time on purpose (``SimulatedClock.sleep_off_loop``): a replay serving a
computation that took that long on the robot. While a thread waits, time moves on and the loop's tasks run
through it; at its time it goes on before anything else at that time; nothing depends on
the machine's load."""

from __future__ import annotations

import asyncio
import threading

from daemon.clock import SimulatedClock


def test_a_thread_waiting_on_simulated_time_lets_the_loops_timers_run_meanwhile() -> None:
    clock = SimulatedClock()
    seen: list[tuple[str, float]] = []

    def computing() -> str:
        clock.sleep_off_loop(2.5)  # a plan that took 2.5 s on the robot
        seen.append(("plan done", clock.monotonic()))
        return "plan"

    async def poll() -> None:
        for _ in range(4):
            await clock.sleep(1.0)
            seen.append(("poll", clock.monotonic()))

    async def body() -> str:
        polling = asyncio.ensure_future(poll())
        plan = await asyncio.to_thread(computing)
        seen.append(("job has the plan", clock.monotonic()))
        await polling
        return plan

    assert clock.run(body()) == "plan"
    assert seen == [
        ("poll", 1.0),
        ("poll", 2.0),
        ("plan done", 2.5),
        ("job has the plan", 2.5),
        ("poll", 3.0),
        ("poll", 4.0),
    ]


def test_a_woken_thread_goes_on_before_the_loop_runs_anything_else_at_that_time() -> None:
    clock = SimulatedClock()
    order: list[str] = []

    def computing() -> None:
        clock.sleep_off_loop(1.0)
        order.append("thread")  # (on the worker thread; the loop waits for it)
        clock.sleep_off_loop(2.0)  # a second call of the same computation
        order.append("thread again")

    async def timer(t: float) -> None:
        await clock.sleep_until(t)
        order.append(f"timer {t:g}")

    async def body() -> None:
        await asyncio.gather(asyncio.to_thread(computing), timer(1.0), timer(2.0), timer(1.5))

    for _ in range(5):  # the same every time, whichever thread the machine runs first
        order.clear()
        clock = SimulatedClock()
        clock.run(body())
        assert order == ["thread", "timer 1", "timer 1.5", "thread again", "timer 2"]


def test_other_work_is_handed_back_while_one_thread_waits_on_the_clock() -> None:
    clock = SimulatedClock()

    def slow() -> float:
        clock.sleep_off_loop(10.0)
        return clock.monotonic()

    def quick() -> float:
        clock.sleep_off_loop(0.0)  # at or past its time: no wait
        return clock.monotonic()

    async def body() -> tuple[float, float, float]:
        waiting = asyncio.ensure_future(asyncio.to_thread(slow))
        at_quick = await asyncio.to_thread(quick)
        after_quick = clock.monotonic()
        return at_quick, after_quick, await waiting

    assert clock.run(body()) == (0.0, 0.0, 10.0)


def test_it_returns_at_once_on_the_loops_thread_and_on_threads_the_loop_does_not_wait_for() -> None:
    clock = SimulatedClock()
    other: list[float] = []

    def foreign() -> None:
        clock.sleep_off_loop(50.0)  # not the clock's executor work: the loop would not know to wait
        other.append(clock.monotonic())

    async def body() -> float:
        clock.sleep_off_loop(100.0)  # on the loop's own thread: cannot wait for itself
        thread = threading.Thread(target=foreign)
        thread.start()
        thread.join()
        return clock.monotonic()

    assert clock.run(body()) == 0.0
    assert other == [0.0]


def test_a_session_that_ends_while_a_thread_waits_on_the_clock_ends() -> None:
    clock = SimulatedClock()
    released = threading.Event()

    def computing() -> None:
        clock.sleep_off_loop(3600.0)
        released.set()

    async def body() -> None:
        task = asyncio.ensure_future(asyncio.to_thread(computing))
        await clock.sleep(1.0)
        task.cancel()  # the job went on without it (a fault): the session ends meanwhile

    clock.run(body())
    assert released.is_set()
