"""The clocks: simulated time that jumps when every task waits, stands still while executor work runs, hands
results back in submission order, steps the world as it advances and paces itself at a speed factor; the
``--speed``/``--transport`` flags and the ``--once`` summary line."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import pytest

from cli.commands.run import _print_summary, time_ratio_line
from cli.main import main
from daemon.app import RunResult
from daemon.clock import RealClock, SimulatedClock, parse_speed
from daemon.job import JobSummary
from drivers.interfaces import Clock, SteppedClock


def test_both_clocks_implement_the_protocol_and_only_the_simulated_one_steps_a_world() -> None:
    assert isinstance(RealClock(), Clock)
    assert isinstance(SimulatedClock(), SteppedClock)
    assert not isinstance(RealClock(), SteppedClock)
    assert (RealClock().simulated, SimulatedClock().simulated) == (False, True)


def test_simulated_time_jumps_to_the_next_timer_and_every_wait_agrees_with_it() -> None:
    clock = SimulatedClock(wall_start=1000.0)
    woke: list[tuple[str, float]] = []

    async def sleeper(name: str, seconds: float) -> None:
        await clock.sleep(seconds)
        woke.append((name, clock.monotonic()))

    async def body() -> None:
        loop = asyncio.get_running_loop()
        await asyncio.gather(sleeper("an hour", 3600.0), sleeper("a second", 1.0), sleeper("a day", 86400.0))
        await asyncio.sleep(5.0)  # asyncio's own timers are on the same time
        assert loop.time() == clock.monotonic() == 86405.0
        with pytest.raises(TimeoutError):
            async with clock.timeout(2.0):
                await asyncio.Event().wait()
        await clock.sleep_until(90000.0)
        never = loop.create_future()
        assert not await clock.wait(never, 10.0)

    clock.run(body())
    assert woke == [("a second", 1.0), ("an hour", 3600.0), ("a day", 86400.0)]
    assert clock.monotonic() == 90010.0
    assert clock.now() == 1000.0 + 90010.0


def test_simulated_time_stands_still_while_executor_work_runs() -> None:
    clock = SimulatedClock()

    def slow() -> float:
        time.sleep(0.05)  # this machine's time, not the simulation's
        return clock.monotonic()

    async def body() -> tuple[float, float, float]:
        ticking = asyncio.create_task(clock.sleep(1e-6))  # a timer due almost at once must wait too
        before = clock.monotonic()
        during = await asyncio.to_thread(slow)
        await ticking
        return before, during, clock.monotonic()

    before, during, after = clock.run(body())
    assert before == during == 0.0
    assert after == pytest.approx(1e-6)


def test_executor_results_come_back_in_submission_order_whichever_thread_finishes_first() -> None:
    clock = SimulatedClock()
    order: list[str] = []
    second_done = threading.Event()

    def first() -> str:
        second_done.wait(5.0)  # finishes after the second one
        return "first"

    def second() -> str:
        second_done.set()
        return "second"

    async def record(work: asyncio.Future[str]) -> None:
        order.append(await work)

    async def body() -> None:
        loop = asyncio.get_running_loop()
        await asyncio.gather(
            record(loop.run_in_executor(None, first)), record(loop.run_in_executor(None, second))
        )

    clock.run(body())
    assert order == ["first", "second"]


def test_steppers_see_every_advance_before_any_task_does_and_can_be_removed() -> None:
    clock = SimulatedClock()
    stepped: list[float] = []
    seen: list[tuple[float, float]] = []
    remove = clock.add_stepper(stepped.append)

    async def body() -> None:
        for _ in range(3):
            await clock.sleep(0.5)
            seen.append((clock.monotonic(), stepped[-1]))
        remove()
        await clock.sleep(0.5)

    clock.run(body())
    assert seen == [(0.5, 0.5), (1.0, 1.0), (1.5, 1.5)]
    assert stepped == [0.5, 1.0, 1.5]


class _SlowHelper:
    """A helper thread handed work from the loop (as the recorder is), slower than the loop: it notes the
    simulated time at which it handled each item."""

    def __init__(self, clock: SimulatedClock) -> None:
        self.clock = clock
        self.items: list[float] = []
        self.handled: list[tuple[float, float]] = []  # (simulated time handed over, simulated time handled)
        self.cond = threading.Condition()
        self.done = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def hand(self, item: float) -> None:
        with self.cond:
            self.items.append(item)
            self.cond.notify_all()

    def caught_up(self, wait_s: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: not self.items, timeout=wait_s)

    def close(self) -> None:
        with self.cond:
            self.done = True
            self.cond.notify_all()
        self.thread.join()

    def _run(self) -> None:
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.items or self.done)
                if not self.items:
                    return
                item = self.items[0]
            threading.Event().wait(0.01)  # slow: this machine's time, never the simulation's
            with self.cond:
                self.handled.append((item, self.clock.monotonic()))
                self.items.pop(0)
                self.cond.notify_all()


def test_simulated_time_does_not_advance_while_a_helper_is_behind_and_then_moves_on() -> None:
    clock = SimulatedClock()
    helper = _SlowHelper(clock)
    remove = clock.add_backlog(helper.caught_up)

    async def body() -> None:
        for _ in range(5):
            for _ in range(3):
                helper.hand(clock.monotonic())
            await clock.sleep(1.0)
        remove()

    try:
        clock.run(body())
    finally:
        helper.close()
    assert len(helper.handled) == 15
    assert all(handed == handled for handed, handled in helper.handled)  # time waited for every item
    assert clock.monotonic() == 5.0
    assert clock.held == 5  # once per step of time: it waited, and only when the helper was behind


def test_at_a_speed_factor_the_clock_waits_for_the_wall_clock_and_never_bursts_to_catch_up(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    wall = {"t": 100.0}
    monkeypatch.setattr("daemon.clock.time.monotonic", lambda: wall["t"])
    clock = SimulatedClock(speed=2.0)
    clock._pace_wall, clock._pace_sim = 100.0, 0.0
    assert clock._paced_wait(1.0) == pytest.approx(0.5)  # 1 simulated s at 2x: half a wall second
    wall["t"] = 100.5
    assert clock._paced_wait(1.0) == pytest.approx(0.0)
    wall["t"] = 103.0  # time stood still for a long computation: 2.5 wall s behind
    assert clock._paced_wait(1.0) == pytest.approx(0.5)  # paced afresh from now, not all at once
    assert (clock._pace_wall, clock._pace_sim) == (103.0, 0.0)


def test_a_simulated_clock_refuses_to_be_waited_on_from_another_event_loop() -> None:
    clock = SimulatedClock()
    with pytest.raises(RuntimeError, match=r"^this coroutine waits on a SimulatedClock but runs on another"):
        asyncio.run(clock.sleep(1.0))


@pytest.mark.parametrize("speed", [0.0, -1.0, 5000.0, float("nan")])
def test_a_speed_out_of_range_is_refused(speed: float) -> None:
    with pytest.raises(ValueError, match=r"choose None \(max\) or 0.1-1000 simulated seconds per second$"):
        SimulatedClock(speed=speed)


def test_parse_speed_takes_max_or_a_factor() -> None:
    assert parse_speed("max") is None
    assert parse_speed("MAX") is None
    assert parse_speed("2.5") == 2.5
    for bad in ("0", "fast", "1e9", "inf", ""):
        with pytest.raises(ValueError, match=r": choose max or 0.1-1000 simulated seconds per second$"):
            parse_speed(bad)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--speed", "0"], "--speed 0: choose max or 0.1-1000 simulated seconds per second"),
        (["--speed", "fast"], "--speed fast: choose max or 0.1-1000 simulated seconds per second"),
        (
            ["--world", "kinematic", "--transport", "pty"],
            "--transport pty: the kinematic cell has no serial devices",
        ),
        (
            ["--world", "mujoco", "--transport", "pty", "--speed", "max"],
            "--speed max: the MuJoCo cell on pseudo-terminals runs in real time (its device simulators keep "
            "wall-clock time); use --transport inprocess to run faster",
        ),
    ],
)
def test_bad_speed_and_transport_flags_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], message: str
) -> None:
    assert main(["run", "--sim", "--once", "--record-dir", str(tmp_path), *flags]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"dishbot run: error: {message}"
    assert not list(tmp_path.glob("*.mcap"))


def test_the_once_summary_says_simulated_and_wall_time_and_their_ratio(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert time_ratio_line(240.9, 31.2) == "simulated 240.9 s in 31.2 s wall (7.7x real time)"
    assert time_ratio_line(1.0, 0.0) == "simulated 1.0 s in 0.0 s wall (- real time)"
    summary = JobSummary(detected=12, planned=10, placed=10, started_at=5.0, ended_at=245.9)
    _print_summary(RunResult(summary, Path("r.mcap"), "done", wall_s=31.2, simulated=True))
    assert capsys.readouterr().out.splitlines() == [
        "job ended in state done",
        "detected 12, planned 10, placed 10, failed 0",
        "grasp failures 0, drops 0, duration 240.9 s",
        "simulated 240.9 s in 31.2 s wall (7.7x real time)",
        "recording r.mcap",
    ]
    _print_summary(RunResult(summary, Path("r.mcap"), "done", wall_s=240.9, simulated=False))
    assert "simulated" not in capsys.readouterr().out  # the robot's job is in real time


def test_the_once_summary_says_how_many_log_lines_a_closed_output_lost(
    capsys: pytest.CaptureFixture[str],
) -> None:
    summary = JobSummary(detected=2, planned=2, placed=2, started_at=0.0, ended_at=10.0)
    _print_summary(RunResult(summary, Path("r.mcap"), "done", log_lines_lost=7))
    assert (
        "log output lost 7 lines (stderr was closed; the recording has them)"
        in capsys.readouterr().out.splitlines()
    )
    _print_summary(RunResult(summary, Path("r.mcap"), "done"))
    assert "log output lost" not in capsys.readouterr().out
