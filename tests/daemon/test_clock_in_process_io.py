"""The simulated loop's looks for I/O: an in-process port is asked whether it has bytes (no readiness pipe,
no system call) and read at the simulated time its device wrote; input from outside (a socket) is still
seen while the loop never waits."""

from __future__ import annotations

import asyncio
import select
import socket

from daemon.clock import SimulatedClock
from drivers.sim.inprocess import InProcessCable, InProcessPort


def test_an_in_process_port_is_read_at_the_time_its_device_wrote_without_its_readiness_pipe() -> None:
    clock = SimulatedClock()
    cable = InProcessCable("ttyTEST", lambda data: None)
    port = cable.open_serial(cable.device_path, 115_200)
    assert isinstance(port, InProcessPort)
    reads: list[tuple[float, bytes]] = []
    quiet_while_waiting: list[bool] = []

    def on_readable() -> None:
        data = port.read(port.in_waiting or 1)
        reads.append((clock.monotonic(), data))
        if not data:  # end-of-file: the cable was pulled
            asyncio.get_running_loop().remove_reader(port)

    async def device() -> None:
        loop = asyncio.get_running_loop()
        loop.add_reader(port, on_readable)
        for t, line in ((0.01, b"one\n"), (0.02, b"two\n")):
            await clock.sleep_until(t)
            cable.write(line)
            quiet_while_waiting.append(port.pending() and not select.select([port.fileno()], [], [], 0)[0])
        await clock.sleep_until(0.03)
        cable.unplug()
        await clock.sleep_until(0.05)

    clock.run(device())
    assert reads == [(0.01, b"one\n"), (0.02, b"two\n"), (0.03, b"")]
    assert quiet_while_waiting == [True, True]


def test_input_from_outside_reaches_a_loop_that_is_never_idle() -> None:
    clock = SimulatedClock()
    outside, inside = socket.socketpair()
    seen: list[bytes] = []

    async def busy() -> int:
        loop = asyncio.get_running_loop()
        loop.add_reader(inside, lambda: seen.append(inside.recv(16)))
        outside.send(b"stop")
        spins = 0
        while not seen and spins < 10_000_000:  # callbacks always ready: the loop never waits for I/O
            spins += 1
            await asyncio.sleep(0)
        loop.remove_reader(inside)
        return spins

    try:
        spins = clock.run(busy())
    finally:
        outside.close()
        inside.close()
    assert seen == [b"stop"]
    assert spins < 10_000_000
    assert clock.monotonic() == 0.0
