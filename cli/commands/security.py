"""``dishbot security init``: the certificates, passwords, robot config and client profiles for remote use."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from daemon.security import DEFAULT_PORT


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "security",
        help="set up TLS certificates, passwords and roles for commanding a robot from other machines",
        description="Set up what commanding a robot from other machines needs (see docs/service.md).",
    )
    verbs = parser.add_subparsers(dest="security_verb", metavar="VERB", required=True)
    init = verbs.add_parser(
        "init",
        help="write a CA, a certificate per identity, passwords, robot.toml and one profile per person",
        description=(
            "Write into DIR: a certificate authority (ca.pem, ca.key), a certificate and key per identity "
            "(the robot's names every --address), the password dictionary (passwords.txt), robot.toml (for "
            "`dishbot run --config`: mutual TLS, passwords and roles filled in) and NAME.profile.toml per "
            "operator and monitor (for `dishbot --profile FILE status`). Operators may call every command; "
            "monitors may watch and ask for status; nobody else may do anything. With --router, also "
            "router.toml (for `dishbot router --config`), and the robot and the profiles go through it. "
            "Keys, passwords and profiles are written mode 0600. Nothing is overwritten without --force."
        ),
    )
    init.add_argument("dir", type=Path, metavar="DIR", help="folder to write into (created if missing)")
    init.add_argument("--robot", required=True, metavar="ID", help="the robot's id (its robot_id)")
    init.add_argument(
        "--address",
        action="append",
        default=[],
        metavar="HOST_OR_IP",
        help="a name or IP address clients reach the robot by (repeatable; the first is the profiles' "
        "endpoint; default: this host's name and loopback)",
    )
    init.add_argument(
        "--operator", action="append", default=[], metavar="NAME", help="someone who may command (repeatable)"
    )
    init.add_argument(
        "--monitor",
        action="append",
        default=[],
        metavar="NAME",
        help="someone who may watch and ask for status only (repeatable)",
    )
    init.add_argument(
        "--router", metavar="HOST_OR_IP", help="a `dishbot router` at this address that everyone connects to"
    )
    init.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        metavar="PORT",
        help=f"the TLS port (default {DEFAULT_PORT})",
    )
    init.add_argument("--force", action="store_true", help="replace the files if DIR already has them")
    init.set_defaults(handler=_init)


def _init(args: argparse.Namespace) -> int:
    from cli import credentials

    plan = credentials.plan(
        args.robot,
        addresses=args.address,
        operators=args.operator,
        monitors=args.monitor,
        router=args.router,
        port=args.port,
    )
    files = credentials.write(plan, args.dir, force=args.force)
    out = sys.stdout
    out.write(f"wrote {len(files)} files to {args.dir}\n")
    robot = plan.robot.name
    out.write(
        f"robot {robot}: copy ca.pem {robot}.pem {robot}.key {credentials.DICTIONARY} robot.toml; "
        "run `dishbot run --config robot.toml`\n"
    )
    if plan.router is not None:
        out.write(
            f"router at {plan.router.addresses[0]}: copy ca.pem router.pem router.key "
            f"{credentials.DICTIONARY} router.toml; run `dishbot router --config router.toml`\n"
        )
    for person in (*plan.operators, *plan.monitors):
        out.write(
            f"{person.role} {person.name}: copy ca.pem {person.name}.pem {person.name}.key "
            f"{person.name}.profile.toml; run `dishbot --profile {person.name}.profile.toml status`\n"
        )
    out.write(f"clients connect to {plan.endpoint()}; keep ca.key off the robot (it signs new identities)\n")
    return 0
