"""``dishbot sim bus``: run the simulated servo chain alone, on a pseudo-terminal, until Ctrl-C.

The first line printed is the device path, so scripts can read it and open the bus like real hardware
(``dishbot servo scan --port "$(dishbot sim bus | head -1)"`` in another shell, or the benchmarks).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from daemon.errors import UsageError
from drivers.dynamixel.tables import model


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("sim", help="run a simulated device on a pseudo-terminal")
    sim_sub = parser.add_subparsers(dest="sim_command", metavar="DEVICE", required=True)
    bus = sim_sub.add_parser(
        "bus",
        help="a simulated Dynamixel chain; prints its device path on the first line, runs until Ctrl-C",
    )
    bus.add_argument("--servos", help="comma-separated ID:MODEL list (default: the thesis arm, ids 1-6)")
    bus.add_argument("--protocol", type=int, default=1, help="Dynamixel protocol version, 1 or 2 (default 1)")
    bus.add_argument("--baud", type=int, default=1_000_000, help="the servos' baud rate (default 1000000)")
    bus.add_argument(
        "--no-wire-timing",
        action="store_true",
        help="answer as fast as the pty allows instead of at the speed of the baud rate",
    )
    bus.set_defaults(handler=_bus)


def parse_servos(text: str) -> list[tuple[int, str]]:
    """``1:MX-64T,2:MX-106T`` -> [(1, "MX-64T"), (2, "MX-106T")]; UsageError naming the bad entry."""
    servos = []
    for entry in filter(None, (e.strip() for e in text.split(","))):
        sid, _, name = entry.partition(":")
        if not sid.isdigit() or not 0 <= int(sid) <= 252:
            raise UsageError(f"--servos entry {entry!r}: the id must be a number in 0..252")
        try:
            model(name)
        except ValueError as e:
            raise UsageError(f"--servos entry {entry!r}: {e}") from e
        servos.append((int(sid), name))
    if not servos:
        raise UsageError("--servos lists no servo")
    ids = [s for s, _ in servos]
    if len(set(ids)) != len(ids):
        raise UsageError("--servos lists an id twice")
    return servos


def _bus(args: argparse.Namespace) -> int:
    from drivers.sim import ServoChainSimulator, default_chain

    servos = parse_servos(args.servos) if args.servos is not None else list(default_chain())
    if args.protocol not in (1, 2):
        raise UsageError(f"--protocol must be 1 or 2, got {args.protocol}")
    try:
        sim = ServoChainSimulator(
            servos, protocol=args.protocol, baudrate=args.baud, wire_timing=not args.no_wire_timing
        )
    except ValueError as e:
        raise UsageError(str(e)) from e
    done = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):  # Ctrl-C, or a supervisor stopping it
        signal.signal(signum, lambda *_: done.set())
    with sim:
        print(sim.device_path, flush=True)
        listing = ", ".join(f"{i}:{m}" for i, m in servos)
        print(
            f"simulating Protocol {args.protocol}.0 at {args.baud} bps: {listing}",
            file=sys.stderr,
            flush=True,
        )
        done.wait()
    return 0
