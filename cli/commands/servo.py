"""``dishbot servo scan|set-id|set-baud``: bring up a Dynamixel chain before the first run.

New servos ship as id 1 (the AX-12A at 1 Mbps, MX and X series at 57600 bps); connect them one at a time,
give each its joint's id and the bus baud rate, then ``scan`` the whole chain.
"""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from daemon.errors import UsageError
from drivers.dynamixel import BusConfig
from drivers.dynamixel.protocol import MAX_ID
from drivers.dynamixel.tables import BAUD_CODES_1, BAUD_CODES_2, MODELS_BY_NUMBER, baud_code
from drivers.errors import BusLost, DriverError

if TYPE_CHECKING:
    from drivers.dynamixel import DynamixelBus


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("servo", help="find Dynamixel servos and change their id or baud rate")
    servo_sub = parser.add_subparsers(dest="servo_command", metavar="ACTION", required=True)

    scan = servo_sub.add_parser("scan", help="list every servo that answers (id, model, baud rate)")
    _bus_flags(scan)
    scan.add_argument("--all-bauds", action="store_true", help="try every baud rate of the protocol in turn")
    scan.add_argument("--max-id", type=int, default=MAX_ID, help=f"highest id to ping (default {MAX_ID})")
    scan.add_argument("--json", action="store_true", help="print JSON instead of the table")
    scan.set_defaults(handler=_scan)

    set_id = servo_sub.add_parser("set-id", help="give the servo at --id the id --new-id (EEPROM)")
    _bus_flags(set_id)
    set_id.add_argument("--id", type=int, required=True, dest="servo_id", help="the servo's present id")
    set_id.add_argument("--new-id", type=int, required=True, help=f"the id to give it (0..{MAX_ID}, unused)")
    set_id.set_defaults(handler=_set_id)

    set_baud = servo_sub.add_parser("set-baud", help="switch the servo at --id to --new-baud (EEPROM)")
    _bus_flags(set_baud)
    set_baud.add_argument("--id", type=int, required=True, dest="servo_id", help="the servo's id")
    set_baud.add_argument("--new-baud", type=int, required=True, help="the baud rate to switch it to")
    set_baud.set_defaults(handler=_set_baud)


def _bus_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        default="/dev/dishbot-servos",
        help="serial device of the bus adapter (default /dev/dishbot-servos, from drivers/udev/)",
    )
    parser.add_argument(
        "--protocol", type=int, default=1, help="Dynamixel protocol version, 1 or 2 (default 1)"
    )
    parser.add_argument(
        "--baud", type=int, default=1_000_000, help="baud rate the servos use now (default 1000000)"
    )


def _config(args: argparse.Namespace, baudrate: int | None = None) -> BusConfig:
    try:
        return BusConfig(args.port, baudrate or args.baud, args.protocol)
    except ValueError as e:
        raise UsageError(str(e)) from e


def _check_id(name: str, value: int) -> None:
    if not 0 <= value <= MAX_ID:
        raise UsageError(f"{name} {value} is outside 0..{MAX_ID}")


# A scan waits this long at each id nobody answers (253 ids: 2.5 s); a command to one known servo waits
# longer, so that a busy computer's late status packet is not taken for a silent servo (a real servo answers
# within a couple of milliseconds, so the wait costs nothing when it does).
_SCAN_TIMEOUT_S = 0.01
_COMMAND_TIMEOUT_S = 0.2


def _open(config: BusConfig, *, read_timeout_s: float = _SCAN_TIMEOUT_S) -> DynamixelBus:
    from daemon.clock import RealClock
    from drivers.dynamixel import DynamixelBus  # dynamixel-sdk

    bus = DynamixelBus(config, clock=RealClock(), read_timeout_s=read_timeout_s, retries=0)
    try:
        bus.open()
    except BusLost as e:
        raise UsageError(str(e)) from e
    return bus


def _model_name(number: int) -> str:
    spec = MODELS_BY_NUMBER.get(number)
    return spec.name if spec else f"unknown ({number})"


def _scan(args: argparse.Namespace) -> int:
    _check_id("--max-id", args.max_id)
    config = _config(args)
    rates = (
        sorted(BAUD_CODES_1 if config.protocol == 1 else BAUD_CODES_2)
        if args.all_bauds
        else [config.baudrate]
    )
    found: list[dict[str, object]] = []
    for rate in rates:
        bus = _open(_config(args, rate))
        try:
            for servo_id, number in bus.scan(range(args.max_id + 1)).items():
                found.append(
                    {"id": servo_id, "model": _model_name(number), "model_number": number, "baud": rate}
                )
        finally:
            bus.close()
    if args.json:
        print(json.dumps({"port": config.port, "protocol": config.protocol, "servos": found}, indent=2))
        return 0
    if not found:
        print(
            f"no servo answered on {config.port} "
            f"(Protocol {config.protocol}.0, {', '.join(map(str, rates))} bps)"
        )
        return 1
    print(f"{'id':>3}  {'model':<12} {'baud':>8}")
    for row in found:
        print(f"{row['id']:>3}  {row['model']!s:<12} {row['baud']:>8}")
    return 0


def _find(bus: DynamixelBus, servo_id: int) -> str:
    number = bus.ping(servo_id, attempts=3)
    if number is None:
        raise UsageError(
            f"no servo answers at id {servo_id} on {bus.config.port} at {bus.config.baudrate} bps; "
            "run `dishbot servo scan --all-bauds`"
        )
    spec = MODELS_BY_NUMBER.get(number)
    if spec is None or spec.protocol != bus.config.protocol:
        raise UsageError(
            f"servo {servo_id} is model {number}, which dishbot does not support on this protocol"
        )
    bus.register(servo_id, spec.name)
    return spec.name


def _set_id(args: argparse.Namespace) -> int:
    _check_id("--id", args.servo_id)
    _check_id("--new-id", args.new_id)
    if args.servo_id == args.new_id:
        raise UsageError(f"--new-id {args.new_id} is the servo's present id; nothing to change")
    bus = _open(_config(args), read_timeout_s=_COMMAND_TIMEOUT_S)
    try:
        name = _find(bus, args.servo_id)
        taken = bus.ping(args.new_id, attempts=2)
        if taken is not None:
            raise UsageError(f"id {args.new_id} is already used by a {_model_name(taken)}; pick a free id")
        bus.set_id(args.servo_id, args.new_id)
    except DriverError as e:
        raise UsageError(str(e)) from e
    finally:
        bus.close()
    print(f"servo {args.servo_id} ({name}) is now id {args.new_id}")
    return 0


def _set_baud(args: argparse.Namespace) -> int:
    _check_id("--id", args.servo_id)
    config = _config(args)
    try:
        code = baud_code(config.protocol, args.new_baud)
    except ValueError as e:
        raise UsageError(str(e)) from e
    bus = _open(config, read_timeout_s=_COMMAND_TIMEOUT_S)
    try:
        name = _find(bus, args.servo_id)
        bus.set_baud(args.servo_id, code, args.new_baud)
    except DriverError as e:
        raise UsageError(str(e)) from e
    finally:
        bus.close()
    print(f"servo {args.servo_id} ({name}) now talks at {args.new_baud} bps")
    return 0
