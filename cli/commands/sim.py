"""``dishbot sim bus`` and ``dishbot sim rig``: simulated devices in a process of their own, until Ctrl-C.

``sim bus`` runs the simulated servo chain alone on a pseudo-terminal. The first line printed is the device
path, so scripts can read it and open the bus like real hardware (``dishbot servo scan --port "$(dishbot sim
bus | head -1)"`` in another shell, or the benchmarks).

``sim rig`` runs the whole simulated cell as the robot's computer sees a robot (``sim.rig``): the servo chain
and the FSR Arduino on pseudo-terminals under stable names, and the depth camera as a camera node publishing
frames on Zenoh (``wire.depth``). It writes a ``backend = "hardware"`` config pointing at them, which
``dishbot run --config FILE`` drives exactly as it drives the robot.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.errors import ConfigError, UsageError

if TYPE_CHECKING:
    import zenoh

    from drivers.interfaces import Clock, RGBDFrame
from drivers.dynamixel.tables import model

RIG_MARK = "# Written by `dishbot sim rig`"
DEFAULT_RIG_LISTEN = "tcp/127.0.0.1:7460"
DEFAULT_CAMERA_KEY = "dishbot/camera/depth"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "sim", help="simulated devices: the servo chain (bus) or the whole cell as separate devices (rig)"
    )
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
    rig = sim_sub.add_parser(
        "rig",
        help="the simulated cell as separate devices (servo chain and FSR on pseudo-terminals, the depth "
        "camera on Zenoh) and a hardware config for `dishbot run --config`; runs until Ctrl-C or SIGTERM",
        description="Run the simulated cell as the robot's computer sees a robot: the servo chain and the "
        "FSR Arduino on pseudo-terminals (linked as DIR/dishbot-servos and DIR/dishbot-fsr), the depth "
        "camera as a camera node publishing frames on Zenoh, in real time. Writes a config with backend = "
        '"hardware" pointing at them: `dishbot run --config FILE [--once]` then drives the rig with the '
        "robot's drivers, perception and recording.",
    )
    rig.add_argument(
        "--world",
        default="mujoco",
        help="the simulated world: mujoco (physics, the default) or kinematic (no dynamics: the kinematic "
        "cell's world, drawn for the camera by MuJoCo's renderer)",
    )
    counter = rig.add_mutually_exclusive_group()
    counter.add_argument("--dataset", type=int, help="the thesis dataset on the counter (default 1)")
    counter.add_argument(
        "--mugs",
        metavar="FILE",
        help='a JSON list of mugs [{"id", "type", "x_m", "y_m"}] on the counter (as `dishbot start --mugs`)',
    )
    rig.add_argument("--seed", type=int, default=0, help="seeds the camera's depth noise (default 0)")
    rig.add_argument(
        "--listen",
        default=DEFAULT_RIG_LISTEN,
        help=f"the camera node's Zenoh endpoint, which the daemon connects to (default {DEFAULT_RIG_LISTEN})",
    )
    rig.add_argument(
        "--camera-key",
        default=DEFAULT_CAMERA_KEY,
        help=f"the key frames are published on ({DEFAULT_CAMERA_KEY})",
    )
    rig.add_argument(
        "--camera-hz", type=float, default=5.0, help="frames published per second (default 5; 0.5-30)"
    )
    rig.add_argument(
        "--config", metavar="FILE", help="a config to start from (the cell, the mug catalogue, the robot id)"
    )
    rig.add_argument(
        "--dir",
        metavar="DIR",
        help="where the device links go (default: the folder of --write-config)",
    )
    rig.add_argument(
        "--write-config",
        metavar="FILE",
        required=True,
        help="the hardware config to write (a file this command wrote before is replaced, no other)",
    )
    rig.set_defaults(handler=_rig)


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


def _rig(args: argparse.Namespace) -> int:
    from daemon.clock import RealClock
    from daemon.config import load_config, to_toml
    from daemon.security import check_endpoint, check_key
    from sim.rig import RIG_WORLDS

    if args.world not in RIG_WORLDS:
        raise UsageError(f"--world {args.world}: choose one of {', '.join(RIG_WORLDS)}")
    if not 0.5 <= args.camera_hz <= 30.0:
        raise UsageError(f"--camera-hz {args.camera_hz:g} is out of range; allowed [0.5, 30]")
    try:
        check_endpoint(args.listen, "--listen")
        check_key(args.camera_key, "--camera-key")
    except ConfigError as e:
        raise UsageError(str(e)) from e
    target = Path(args.write_config)
    _check_writable(target)
    base = load_config(Path(args.config) if args.config else None)
    counter = _counter(args, base)
    directory = Path(args.dir) if args.dir else target.resolve().parent

    from sim.rig import FSR_LINK, SERVO_LINK, open_rig

    config_data = _rig_config(
        base.to_dict(),
        servo_port=str((directory / SERVO_LINK).absolute()),
        fsr_port=str((directory / FSR_LINK).absolute()),
        connect=args.listen,
        key=args.camera_key,
    )
    load_config(overrides=config_data)  # the file must load as written: checked before anything starts
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    import zenoh

    from daemon.zenoh_session import error_text, session_config

    clock = RealClock()

    def collided(c: Any) -> None:
        print(f"rig: tray collision {c.a} / {c.b}", file=sys.stderr, flush=True)

    with contextlib.ExitStack() as stack:
        try:
            session = zenoh.open(session_config(listen=(args.listen,), connect=()))
        except zenoh.ZError as e:
            raise UsageError(f"--listen {args.listen}: cannot listen: {error_text(e)}") from e
        stack.callback(session.close)
        try:
            rig = stack.enter_context(
                open_rig(
                    base.cell,
                    counter,
                    directory=directory,
                    clock=clock,
                    world=args.world,
                    seed=args.seed,
                    start_pose_rad=base.sim.start_q_rad,
                    on_collision=collided,
                )
            )
        except (OSError, ValueError) as e:
            raise UsageError(f"sim rig: {e}") from e
        header = (
            f"{RIG_MARK} ({args.world}, {len(counter)} mugs): `dishbot run --config {target}` drives it.\n"
        )
        target.write_text(header + to_toml(config_data), encoding="utf-8")
        print(
            f"rig ready: {len(counter)} mugs; servos {rig.servo_port}, fsr {rig.fsr_port}, camera on "
            f"{args.listen} key {args.camera_key}; config {target}; world {args.world}",
            flush=True,
        )
        _publish(session, args.camera_key, rig.render, clock=clock, period_s=1.0 / args.camera_hz, stop=stop)
    print("rig stopped", file=sys.stderr, flush=True)
    return 0


def _publish(
    session: zenoh.Session,
    key: str,
    render: Callable[[], RGBDFrame],
    *,
    clock: Clock,
    period_s: float,
    stop: threading.Event,
) -> None:
    """Render and publish a frame every ``period_s`` of ``clock``'s time until ``stop`` (a camera node's
    loop; the rig runs on the wall clock)."""
    from wire.depth import encode_depth

    publisher = session.declare_publisher(key)
    seq = 0
    next_at = clock.monotonic()
    while not stop.is_set():
        frame = render()
        payload, attachment = encode_depth(frame.depth_m, seq=seq, t=clock.now())
        publisher.put(payload, attachment=attachment)
        seq += 1
        next_at = max(next_at + period_s, clock.monotonic())
        stop.wait(max(0.0, next_at - clock.monotonic()))


def _check_writable(target: Path) -> None:
    if target.is_dir():
        raise UsageError(f"--write-config {target}: is a folder; name a file")
    if target.exists():
        try:
            first = target.read_text(encoding="utf-8").split("\n", 1)[0]
        except (OSError, UnicodeDecodeError) as e:
            raise UsageError(f"--write-config {target}: exists and cannot be read ({e})") from e
        if not first.startswith(RIG_MARK):
            raise UsageError(f"--write-config {target}: exists, not written by a rig; choose a new name")
    if not target.resolve().parent.is_dir():
        raise UsageError(f"--write-config {target}: the folder {target.resolve().parent} does not exist")


def _counter(args: argparse.Namespace, config: Any) -> list[Any]:
    """The rig's counter mugs: the listed ones, else the dataset's (default 1), on the config's cell."""
    from cli.mugs_file import listed_mugs
    from description import thesis
    from sim.counter import dataset_counter, listed_counter, require_cell_tray

    if args.dataset is not None and not 1 <= args.dataset <= len(thesis.DATASETS):
        raise UsageError(f"--dataset {args.dataset}: choose a dataset 1-{len(thesis.DATASETS)}")
    listed = listed_mugs(args.mugs, config) if args.mugs is not None else None
    try:
        if listed is not None:
            entries = [(m.mug_id, m.type, m.x_m, m.y_m) for m in listed]
            counter = listed_counter(entries, config.cell, config.mug_catalogue())
        else:
            counter = dataset_counter(args.dataset or 1, config.cell, config.mug_catalogue())
        require_cell_tray(counter, config.cell)
    except (KeyError, ValueError) as e:
        raise UsageError(f"sim rig: {e}") from e
    return list(counter.mugs)


def _rig_config(
    effective: dict[str, Any], *, servo_port: str, fsr_port: str, connect: str, key: str
) -> dict[str, Any]:
    """The effective config with the hardware backend on the rig's devices."""
    hardware = dict(effective["hardware"])
    hardware.update(
        servo_port=servo_port,
        camera="zenoh",
        # The simulated servos answer from a Python thread over a pty, not from firmware: give a status
        # packet 50 ms and three tries (a real chain needs under 20 ms), as the MuJoCo cell on ptys does.
        read_timeout_s=0.05,
        retries=3,
        zenoh_camera={"connect": connect, "key": key},
        fsr={**hardware["fsr"], "port": fsr_port},
    )
    return {**effective, "backend": "hardware", "hardware": hardware}
