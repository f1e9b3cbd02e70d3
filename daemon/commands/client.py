"""``dishbot status|start|pause|resume|stop|estop|reset``: command a running daemon over Zenoh.

Each verb sends one query to ``dishbot/<robot>/cmd/<verb>`` from a short-lived peer session that connects to
``--connect`` (multicast scouting off) and prints the JSON reply. Exit 0 when the daemon accepted the command,
1 when it refused it or did not answer.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping
from typing import Any

from daemon.config import PLANNER_COSTS, PLANNER_FITNESS, check_endpoint
from daemon.errors import ConfigError, UsageError
from description import thesis
from planning.placement import METHODS

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

_HELP = {
    "status": "print the daemon's state, job progress and the commands allowed now",
    "start": "start a loading job (simulation: --dataset or --mugs set the counter up first)",
    "pause": "stop motion where it is; resume continues from there",
    "resume": "continue a paused job where it stopped",
    "stop": "abandon the job: stop motion, go back to idle",
    "estop": "emergency stop: stop the arm, then switch its torque off; only reset leaves",
    "reset": "leave fault or estop for idle",
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    for verb, text in _HELP.items():
        parser = sub.add_parser(verb, help=f"daemon command: {text}", description=text.capitalize() + ".")
        _common(parser)
        if verb == "start":
            _start_flags(parser)
        parser.set_defaults(handler=_send, verb=verb)


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect",
        default=DEFAULT_ENDPOINT,
        metavar="ENDPOINT",
        help=f"the daemon's Zenoh endpoint (default {DEFAULT_ENDPOINT})",
    )
    parser.add_argument(
        "--robot", default="dishbot", metavar="ID", help="the daemon's robot id (default dishbot)"
    )
    parser.add_argument(
        "--timeout", type=float, default=5.0, metavar="S", help="seconds to wait for the reply (default 5)"
    )
    parser.add_argument("--json", action="store_true", help="print the reply as one JSON document")


def _start_flags(parser: argparse.ArgumentParser) -> None:
    counter = parser.add_mutually_exclusive_group()
    counter.add_argument(
        "--dataset",
        type=int,
        metavar="N",
        help=f"simulation: put placement dataset N (1-{len(thesis.DATASETS)}) on the counter first",
    )
    counter.add_argument(
        "--mugs",
        metavar="FILE",
        help='simulation: a JSON list of mugs [{"id", "type", "x_m", "y_m"}] to put on the counter first',
    )
    parser.add_argument("--method", choices=METHODS, help="placement method for this job")
    parser.add_argument("--cost", choices=PLANNER_COSTS, help="placement cost function for this job")
    parser.add_argument("--fitness", choices=PLANNER_FITNESS, help="fitness method for this job")
    parser.add_argument("--time-limit", type=float, metavar="S", help="placement time budget in seconds")


def _send(args: argparse.Namespace) -> int:
    try:
        endpoint = check_endpoint(args.connect, "--connect")
    except ConfigError as e:
        raise UsageError(str(e)) from e
    if not 0 < args.timeout <= 600:
        raise UsageError(f"--timeout {args.timeout:g}: choose 0-600 seconds")
    body = _start_body(args) if args.verb == "start" else {}
    reply = request(endpoint, args.robot, args.verb, body, timeout_s=args.timeout)
    if reply is None:
        print(
            f"dishbot {args.verb}: no daemon answered for robot {args.robot!r} at {endpoint} "
            f"within {args.timeout:g} s",
            file=sys.stderr,
        )
        return 1
    if args.json:
        print(json.dumps(reply, indent=2))
    elif reply.get("ok"):
        print(_readable(reply))
    else:
        print(f"dishbot {args.verb}: refused: {reply.get('error')}", file=sys.stderr)
    return 0 if reply.get("ok") else 1


def request(
    endpoint: str, robot: str, verb: str, body: Mapping[str, object], *, timeout_s: float
) -> dict[str, Any] | None:
    """Send one command and return the decoded reply, or None when nobody answered in time."""
    import zenoh

    from daemon.zenoh_session import encode, key, session_config

    with zenoh.open(session_config(listen=[], connect=[endpoint])) as session:
        payload = encode(body) if body else b""
        for reply in session.get(key(robot, f"cmd/{verb}"), payload=payload, timeout=timeout_s):
            if reply.ok is not None:
                decoded: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
                return decoded
            return {"ok": False, "error": reply.err.payload.to_string() if reply.err else "error reply"}
    return None


def _start_body(args: argparse.Namespace) -> dict[str, object]:
    body: dict[str, object] = {}
    if args.dataset is not None:
        body["dataset"] = args.dataset
    if args.mugs is not None:
        try:
            with open(args.mugs, encoding="utf-8") as f:
                body["mugs"] = json.load(f)
        except OSError as e:
            raise UsageError(f"--mugs {args.mugs}: cannot read it: {e.strerror}") from e
        except json.JSONDecodeError as e:
            raise UsageError(f"--mugs {args.mugs}: not valid JSON: {e.msg} at line {e.lineno}") from e
    planner = {
        name: value
        for name, value in (
            ("method", args.method),
            ("cost", args.cost),
            ("fitness", args.fitness),
            ("time_limit_s", args.time_limit),
        )
        if value is not None
    }
    if planner:
        body["planner"] = planner
    return body


def _readable(reply: Mapping[str, Any]) -> str:
    lines = [f"state: {reply.get('state')}"]
    if "mugs_total" in reply:
        lines.append(
            f"mugs: {reply.get('mugs_placed')} placed of {reply.get('mugs_planned')} planned, "
            f"{reply.get('mugs_total')} seen, {reply.get('mugs_failed')} failed; "
            f"current {reply.get('current_mug') or '-'}"
        )
    if "allowed" in reply:
        lines.append(f"allowed: {', '.join(reply['allowed'])}")
    return "\n".join(lines)
