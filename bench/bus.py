"""``dishbot bench bus``: how fast the Dynamixel bus cycles and what it costs the event loop.

The simulated chain runs in its own process (``dishbot sim bus``), answering at the speed of a real
1 Mbps bus, so the numbers are those of the driver, not of a simulator sharing its interpreter.
Measured: packet encode/decode time, the full bus cycle (sync write of every goal + read of every joint)
on Protocol 1.0 and 2.0, and the event loop's wake-up lateness (p99, target <= 5 ms) while the arm
streams a trajectory at 50 Hz — idle, with the simulator in another process, and with it on a pty in this
one (as ``dishbot run --sim --transport pty`` has it). The driver runs on the wall clock, as on the robot.

Then what the simulated cells pay, in CPU time (this machine's load moves wall time, much less CPU time):
a bus transaction as the cells run it (the real bus on dynamixel-sdk, inline on a simulated clock's loop,
to the in-process servo chain simulator: the control tick's sync write and read of the arm, the gripper's
read), and one wake-up of a task on the simulated clock (a timer, one loop iteration, time moved on).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import math
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence

from cli.commands.output import add_json_flag, emit
from drivers.dynamixel import BusConfig, thesis_joints
from drivers.dynamixel import protocol as p

X_CHAIN = (
    (1, "XM430-W350"),
    (2, "XM430-W350"),
    (3, "XM430-W350"),
    (4, "XL430-W250"),
    (5, "XL330-M288"),
    (6, "XL330-M288"),
)
JITTER_TARGET_MS = 5.0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "bus", help="Dynamixel bus cycle rate, packet codec time, event-loop jitter at 50 Hz"
    )
    parser.add_argument("--seconds", type=float, default=3.0, help="length of each timed phase (default 3)")
    add_json_flag(parser)
    parser.set_defaults(handler=_run)


@contextlib.contextmanager
def simulated_bus(servos: Sequence[tuple[int, str]], protocol: int) -> Iterator[str]:
    """Start ``dishbot sim bus`` in a child process; yield its device path."""
    listing = ",".join(f"{i}:{m}" for i, m in servos)
    child = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "sim", "bus", "--servos", listing, "--protocol", str(protocol)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert child.stdout is not None
        path = child.stdout.readline().strip()
        if not path:
            raise RuntimeError("`dishbot sim bus` exited before printing its device path")
        yield path
    finally:
        child.terminate()
        child.wait(timeout=5)


def _codec_us(repeats: int = 2000) -> tuple[float, float]:
    items = [(i, p.le(2048 + i, 2) + p.le(100, 2)) for i in range(1, 7)]
    start = time.perf_counter()
    for _ in range(repeats):
        p.sync_write(1, 30, 4, items)
    encode = (time.perf_counter() - start) / repeats * 1e6
    stream = b"".join(p.encode_status(1, i, 0, bytes(8)) for i in range(1, 7))
    start = time.perf_counter()
    for _ in range(repeats):
        p.Framer(1).feed(stream)
    decode = (time.perf_counter() - start) / repeats / 6 * 1e6
    return encode, decode


def _cycle(
    path: str, protocol: int, servos: Sequence[tuple[int, str]], seconds: float
) -> tuple[list[float], int]:
    """Durations of back-to-back bus cycles, and how many answers had to be asked for again."""
    from daemon.clock import RealClock
    from drivers.dynamixel import DynamixelBus

    ids = [i for i, _ in servos]
    with DynamixelBus(BusConfig(path, protocol=protocol), clock=RealClock()) as bus:  # type: ignore[arg-type]
        bus.verify(servos)
        goals = dict.fromkeys(ids, (0.1, 1.0))
        times = []
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            t0 = time.perf_counter()
            bus.write_goals(goals)
            bus.read_states(ids)
            times.append(time.perf_counter() - t0)
        retries = sum(c.retries for c in bus.counters.values())
    return times, retries


def _median_chunk_us(chunks: Sequence[float], per_chunk: int) -> float:
    return statistics.median(chunks) / per_chunk * 1e6


def _inprocess_transaction_us(cycles: int, chunks: int = 5) -> float:
    """CPU microseconds per bus transaction in the simulated cells' shape: per 20 ms tick a sync write of
    five goals, a read of the five arm servos and one of the gripper, inline on a simulated clock over the
    in-process simulator; the median of ``chunks`` runs of ``cycles`` ticks."""
    from daemon.clock import SimulatedClock
    from drivers.dynamixel import DynamixelBus, ServoChain
    from drivers.sim import ServoChainSimulator, default_chain
    from drivers.sim.plant import FirstOrderPlant

    def _torque_on(bus: DynamixelBus) -> None:
        for servo_id in range(1, 7):
            bus.write_register(servo_id, "torque_enable", 1)

    clock = SimulatedClock()
    arm = [1, 2, 3, 4, 5]
    spent: list[float] = []

    async def main() -> None:
        sim = ServoChainSimulator(default_chain(), plant=FirstOrderPlant(clock=clock.monotonic))
        sim.start_in_process(clock)
        chain = ServoChain(
            BusConfig(sim.device_path),
            default_chain(),
            clock=clock,
            open_serial=sim.open_serial,
            inline=True,
        )
        try:
            async with chain:
                await chain.call(_torque_on)
                for _ in range(chunks):
                    start = time.process_time()
                    for k in range(cycles):
                        goals = {i: (0.3 * math.sin(0.01 * k + i), 1.0) for i in arm}
                        await chain.call(functools.partial(DynamixelBus.write_goals, goals=goals))
                        await chain.call(lambda bus: bus.read_states(arm))
                        await chain.call(lambda bus: bus.read_states([6]))
                        await clock.sleep(0.02)
                    spent.append(time.process_time() - start)
        finally:
            sim.stop()

    clock.run(main())
    return _median_chunk_us(spent, 3 * cycles)


def _simulated_wake_us(wakes: int, chunks: int = 5) -> float:
    """CPU microseconds per wake-up of a task sleeping on a simulated clock (``sleep_until`` the next 20
    ms: a timer, a loop iteration and time moved on); the median of ``chunks`` runs."""
    from daemon.clock import SimulatedClock

    clock = SimulatedClock()
    spent: list[float] = []

    async def main() -> None:
        for _ in range(chunks):
            start = time.process_time()
            t = clock.monotonic()
            for _ in range(wakes):
                t += 0.02
                await clock.sleep_until(t)
            spent.append(time.process_time() - start)

    clock.run(main())
    return _median_chunk_us(spent, wakes)


async def _jitter(path: str, seconds: float, *, with_bus: bool) -> tuple[list[float], float]:
    """Wake-up lateness of a 1 ms sleeper, while (or without) the arm following a trajectory at 50 Hz."""
    import numpy as np

    from daemon.clock import RealClock
    from drivers.dynamixel import DynamixelArm, ServoChain
    from drivers.interfaces import JointTrajectory
    from drivers.sim import default_chain

    lateness: list[float] = []
    loop = asyncio.get_running_loop()

    async def probe(stop: asyncio.Event) -> None:
        while not stop.is_set():
            t0 = loop.time()
            await asyncio.sleep(0.001)
            lateness.append(loop.time() - t0 - 0.001)

    stop = asyncio.Event()
    probe_task = asyncio.create_task(probe(stop))
    rate = 0.0
    if with_bus:
        async with (
            ServoChain(BusConfig(path), default_chain()[:5], clock=RealClock()) as chain,
            DynamixelArm(chain, thesis_joints()) as arm,
        ):
            times = np.linspace(0.0, seconds, int(seconds * 50) + 1)
            positions = np.array(
                [[0.3 * math.sin(2 * math.pi * 0.5 * t + k) for k in range(5)] for t in times]
            )
            start = loop.time()
            await arm.follow(JointTrajectory(arm.joint_names, times, positions))
            rate = len(times) / (loop.time() - start)
            await arm.relax()
    else:
        await asyncio.sleep(seconds)
    stop.set()
    await probe_task
    return lateness, rate


def _pct(values: Sequence[float], q: float) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(values), q))


def _run(args: argparse.Namespace) -> int:
    from drivers.sim import ServoChainSimulator, default_chain

    encode_us, decode_us = _codec_us()
    rows: list[list[object]] = [
        ["sync write encode (6 servos)", round(encode_us, 1), "us", ""],
        ["status packet decode", round(decode_us, 1), "us/packet", ""],
    ]
    for protocol, servos in ((1, default_chain()), (2, X_CHAIN)):
        with simulated_bus(servos, protocol) as path:
            times, retries = _cycle(path, protocol, servos, args.seconds)
        rows.append(
            [
                f"bus cycle rate, Protocol {protocol}.0, 6 servos",
                round(len(times) / sum(times), 1),
                "Hz",
                ">= 50",
            ]
        )
        rows.append([f"bus cycle p99, Protocol {protocol}.0", round(_pct(times, 99) * 1e3, 2), "ms", ""])
        rows.append(
            [f"retried answers, Protocol {protocol}.0", retries, f"of {len(times) * len(servos)}", ""]
        )
    idle, _ = asyncio.run(_jitter("", args.seconds, with_bus=False))
    with simulated_bus(default_chain(), 1) as path:
        busy, rate = asyncio.run(_jitter(path, args.seconds, with_bus=True))
    with ServoChainSimulator(default_chain()) as sim:  # on a pty in this interpreter (--transport pty)
        shared, _ = asyncio.run(_jitter(sim.device_path, args.seconds, with_bus=True))
    rows.append(["control loop rate (arm.follow)", round(rate, 1), "Hz", "50"])
    rows.append(["event-loop jitter p99, idle", round(_pct(idle, 99) * 1e3, 3), "ms", ""])
    rows.append(
        [
            "event-loop jitter p99, bus at 50 Hz",
            round(_pct(busy, 99) * 1e3, 3),
            "ms",
            f"<= {JITTER_TARGET_MS:g}",
        ]
    )
    rows.append(["event-loop jitter max, bus at 50 Hz", round(max(busy) * 1e3, 3), "ms", ""])
    rows.append(
        [
            "event-loop jitter p99, bus at 50 Hz, pty simulator in this process",
            round(_pct(shared, 99) * 1e3, 3),
            "ms",
            "",
        ]
    )
    cycles = max(50, int(args.seconds * 300))
    rows.append(
        [
            "in-process transaction CPU, inline on a simulated clock (cells)",
            round(_inprocess_transaction_us(cycles), 1),
            "us",
            "",
        ]
    )
    rows.append(
        [
            "simulated-clock wake-up CPU (timer + loop iteration)",
            round(_simulated_wake_us(cycles * 3), 1),
            "us",
            "",
        ]
    )
    emit(
        "bench bus",
        ["metric", "value", "unit", "target"],
        rows,
        as_json=args.json,
        extra={"jitter_samples": len(busy), "median_jitter_ms": round(statistics.median(busy) * 1e3, 3)},
    )
    return 0
