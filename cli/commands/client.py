"""``dishbot status|start|pause|resume|stop|estop|reset`` and ``dishbot list``: talk to running daemons.

Each verb opens a short-lived Zenoh client session to ``--connect`` (or the profile's endpoint, with its
certificate and password), sends one query to ``dishbot/<robot>/cmd/<verb>`` and prints the reply. With
``--robot '*'`` ``status`` lists every robot that answers and ``estop`` stops every robot it reaches; the
other verbs go to one named robot only. Exit 0 when every daemon asked accepted the command, 1 when one
refused it or none answered, 2 for bad input (nothing is sent).

When nothing answers, the verb says why as far as it can tell: nothing listens at the endpoint, the
endpoint refused this identity, the robot is alive but did not answer (access control lets a monitor ask
only for ``status``), or other robots are there but not the one named.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from daemon.errors import ConfigError, UsageError
from daemon.security import (
    DEFAULT_PORT,
    FLEET_VERBS,
    MONITOR_VERBS,
    Profile,
    check_endpoint,
    check_robot,
    endpoint_host,
    load_profile,
    role_may,
)
from description import thesis

# Zenoh is imported when a verb runs: `dishbot --help` and the verbs' --help load none of it.
if TYPE_CHECKING:
    import zenoh

    from wire.messages import Reply, UnsetType

T = TypeVar("T")

DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"  # where `dishbot run` listens by default
DEFAULT_ROBOT = "dishbot"
PROFILE_ENV = "DISHBOT_PROFILE"

_HELP = {
    "status": "print the daemon's state, job progress and the commands allowed now",
    "start": "start a loading job (simulation: --dataset or --mugs set the counter up first)",
    "pause": "stop motion where it is; resume continues from there",
    "resume": "continue a paused job where it stopped",
    "stop": "abandon the job: stop motion, go back to idle",
    "estop": "emergency stop: stop the arm, then switch its torque off; only reset leaves",
    "reset": "leave fault or estop for idle",
}


class Unreachable(ConnectionError):
    """No Zenoh session could be opened to the endpoint; the message says what was found there."""


@dataclass(frozen=True, slots=True)
class Target:
    """Where a verb connects, which robot (or ``*``) it addresses, and as whom."""

    endpoint: str
    robot: str
    profile: Profile | None = None

    @property
    def many(self) -> bool:
        return self.robot == "*"

    def settings(self) -> dict[str, object]:
        return self.profile.settings() if self.profile is not None else {}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    for verb, text in _HELP.items():
        parser = sub.add_parser(verb, help=f"daemon command: {text}", description=text.capitalize() + ".")
        add_target_flags(parser, many=verb in FLEET_VERBS)
        _timeout_flags(parser)
        if verb == "start":
            _start_flags(parser)
        parser.set_defaults(handler=_send, verb=verb)
    parser = sub.add_parser(
        "list",
        help="list the robots alive at the endpoint (their liveliness tokens)",
        description="List the robots whose daemons are alive at the endpoint (or behind its router).",
    )
    add_target_flags(parser, many=False, robot=False)
    _timeout_flags(parser, default=2.0)
    parser.set_defaults(handler=_list)


def add_target_flags(parser: argparse.ArgumentParser, *, many: bool, robot: bool = True) -> None:
    """``--connect``, ``--robot`` and ``--profile`` (after the verb; ``dishbot --profile F`` before it)."""
    parser.add_argument(
        "--connect",
        metavar="ENDPOINT",
        help=f"the daemon's (or router's) Zenoh endpoint (default: the profile's, else {DEFAULT_ENDPOINT})",
    )
    if robot:
        every = "; '*' addresses every robot that answers" if many else ""
        parser.add_argument(
            "--robot",
            metavar="ID",
            help=f"the daemon's robot id (default: the profile's, else {DEFAULT_ROBOT}{every})",
        )
    parser.add_argument(
        "--profile",
        metavar="FILE",
        default=argparse.SUPPRESS,  # keeps a `dishbot --profile FILE VERB` given before the verb
        help=f"connect with this profile (dishbot security init writes one; also ${PROFILE_ENV})",
    )


def _timeout_flags(parser: argparse.ArgumentParser, default: float = 5.0) -> None:
    parser.add_argument(
        "--timeout",
        type=float,
        default=default,
        metavar="S",
        help=f"seconds to wait for replies (default {default:g})",
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
    parser.add_argument("--method", metavar="NAME", help="placement method for this job (as dishbot plan)")
    parser.add_argument("--cost", metavar="NAME", help="placement cost function for this job: bpc, upc or ec")
    parser.add_argument("--fitness", metavar="NAME", help="fitness method for this job: rf or ws")
    parser.add_argument("--time-limit", type=float, metavar="S", help="placement time budget in seconds")


def target(args: argparse.Namespace, *, many: bool = False) -> Target:
    """The endpoint, robot and identity from the flags, the profile (flag or ``$DISHBOT_PROFILE``) and the
    defaults, in that order; bad values raise ``UsageError``."""
    path = getattr(args, "profile", None) or os.environ.get(PROFILE_ENV) or None
    try:
        profile = load_profile(Path(path)) if path else None
        endpoint = check_endpoint(
            args.connect or (profile.endpoint if profile else DEFAULT_ENDPOINT), "--connect"
        )
        robot_flag = getattr(args, "robot", None)
        robot = check_robot(
            robot_flag if robot_flag is not None else (profile.robot if profile else DEFAULT_ROBOT),
            "--robot",
            many=many,
        )
    except ConfigError as e:
        raise UsageError(str(e)) from e
    if not 0 < args.timeout <= 600:
        raise UsageError(f"--timeout {args.timeout:g}: choose 0-600 seconds")
    return Target(endpoint, robot, profile)


@contextmanager
def client_session(t: Target) -> Iterator[zenoh.Session]:
    """A Zenoh client session to ``t.endpoint``; ``Unreachable`` (saying why) when none opens."""
    import zenoh

    from daemon.zenoh_session import session_config

    config = session_config(listen=[], connect=[t.endpoint], mode="client", settings=t.settings())
    try:
        session = zenoh.open(config)
    except zenoh.ZError as e:
        raise Unreachable(why_unreachable(t)) from e
    with session:
        yield session


def why_unreachable(t: Target) -> str:
    """What stands at an endpoint no session could be opened to, as far as a plain TCP probe tells."""
    host, port = endpoint_host(t.endpoint), int(t.endpoint.rsplit(":", 1)[1])
    try:
        with socket.create_connection((host, port), timeout=2.0):
            pass
    except OSError as e:
        reason = e.strerror or type(e).__name__
        return f"cannot connect to {t.endpoint}: {reason} (is the daemon running, is the address right?)"
    if t.endpoint.startswith("tls/"):
        return (
            f"{t.endpoint} refused this client: the TLS handshake or the password failed (check the "
            "profile's certificate, key, CA and password)"
        )
    return (
        f"{t.endpoint} accepts TCP but opened no Zenoh session (a TLS-only or password-protected robot? "
        "connect with its profile)"
    )


def request(
    endpoint: str,
    robot: str,
    verb: str,
    body: Mapping[str, object],
    *,
    timeout_s: float,
    profile: Profile | None = None,
) -> dict[str, Any] | None:
    """Send one command to one robot and return the decoded reply, or None when nobody answered in time;
    raises ``Unreachable`` when no session opens."""
    t = Target(endpoint, robot, profile)
    with client_session(t) as session:
        replies = ask(session, t, verb, body, timeout_s=timeout_s)
    return replies[0] if replies else None


def ask(
    session: zenoh.Session, t: Target, verb: str, body: Mapping[str, object], *, timeout_s: float
) -> list[dict[str, Any]]:
    """Every reply to ``cmd/<verb>`` from the robots ``t`` addresses, decoded (error replies too)."""
    import zenoh

    from daemon.zenoh_session import encode, key

    payload = encode(body) if body else b""
    out = []
    for reply in session.get(
        key(t.robot, f"cmd/{verb}"), payload=payload, timeout=timeout_s, target=zenoh.QueryTarget.ALL
    ):
        sample = reply.ok if reply.ok is not None else reply.err
        raw = sample.payload.to_bytes() if sample is not None else b""
        try:
            decoded = json.loads(raw)
        except ValueError:
            decoded = None
        if not isinstance(decoded, dict):
            if reply.ok is None:  # Zenoh's own error (a timeout), not a daemon's answer
                continue
            decoded = {"ok": False, "error": f"not a JSON object: {raw[:80].decode('utf-8', 'replace')!r}"}
        if reply.ok is None:
            decoded["ok"] = False
        out.append(decoded)
    return out


def alive_robots(session: zenoh.Session, *, timeout_s: float) -> list[str]:
    """The robot ids whose liveliness tokens (``dishbot/<id>/alive``) this session can see, sorted."""
    from daemon.zenoh_session import key

    robots = {
        str(r.ok.key_expr).split("/")[1]
        for r in session.liveliness().get(key("*", "alive"), timeout=timeout_s)
        if r.ok is not None
    }
    return sorted(robots)


def _send(args: argparse.Namespace) -> int:
    verb = args.verb
    t = target(args, many=True)
    if t.many and verb not in FLEET_VERBS:
        raise UsageError(
            f"--robot '*': {verb} goes to one robot at a time; name it (only "
            f"{' and '.join(FLEET_VERBS)} go to every robot at once)"
        )
    body = _start_body(args) if verb == "start" else {}
    try:
        with client_session(t) as session:
            began = time.monotonic()
            replies = ask(session, t, verb, body, timeout_s=args.timeout)
            # Access control drops a query it refuses at once, and Zenoh then ends it with no reply; a
            # daemon that is merely slow leaves it open until the timeout.
            refused = time.monotonic() - began < 0.9 * args.timeout
            silent = _silence(session, t, verb, args.timeout, refused=refused) if not replies else ""
    except Unreachable as e:
        print(f"dishbot {verb}: {e}", file=sys.stderr)
        return 1
    if not replies:
        from daemon.zenoh_session import encode, transport_limit_bytes

        size = len(encode(body)) if body else 0
        if size > transport_limit_bytes(0):  # what every daemon's transport takes, whatever its limit
            silent += f" (the command is {size} bytes: more than a daemon accepts by default)"
        print(f"dishbot {verb}: {silent}", file=sys.stderr)
        return 1
    for reply in replies:
        _narrow_to_role(reply, t)
    if t.many:
        return _print_fleet(verb, replies, as_json=args.json)
    reply = replies[0]
    stranger = _stranger(reply, t.robot)
    if stranger:
        print(f"dishbot {verb}: {stranger}", file=sys.stderr)
        return 1
    view = reply_of(reply)
    if args.json:
        print(json.dumps(reply, indent=2))
    elif view.ok:
        print(_readable(view))
    else:
        print(f"dishbot {verb}: refused by robot {t.robot!r}: {_shown(view.error)}", file=sys.stderr)
    return 0 if view.ok else 1


def _silence(session: zenoh.Session, t: Target, verb: str, timeout_s: float, *, refused: bool) -> str:
    """Why no robot answered, from the liveliness tokens still visible and whether the query was ended at
    once (``refused``: access control dropped it) or only by the timeout."""
    alive = alive_robots(session, timeout_s=min(timeout_s, 2.0))
    if alive and (t.robot in alive or t.many) and refused:
        where = f"robot {t.robot!r}" if not t.many else f"the robots ({', '.join(alive)})"
        return f"{where} at {t.endpoint} refused {verb}: access control does not let it through {_who(t)}"
    if t.many and alive:
        return (
            f"robots alive at {t.endpoint} ({', '.join(alive)}) did not answer {verb} within "
            f"{timeout_s:g} s: the daemons may be busy, or the link slow"
        )
    if t.many:
        return f"no robot answered at {t.endpoint} within {timeout_s:g} s"
    if t.robot in alive:
        return (
            f"robot {t.robot!r} is alive at {t.endpoint} but did not answer {verb} within {timeout_s:g} s: "
            "the daemon may be busy, or the link slow"
        )
    if alive:
        return f"no robot {t.robot!r} at {t.endpoint}; robots alive there: {', '.join(alive)}"
    return f"no daemon answered for robot {t.robot!r} at {t.endpoint} within {timeout_s:g} s"


def _who(t: Target) -> str:
    """Whose command was refused, and what that identity may do, as far as the profile says."""
    profile = t.profile
    if profile is None or not profile.user:
        return "for this client (a robot with roles takes commands only from a profile's identity)"
    if profile.role == "monitor":
        return f"for monitor {profile.user} (a monitor may only watch and ask for {', '.join(MONITOR_VERBS)})"
    role = f"{profile.role} " if profile.role else ""
    return f"for {role}{profile.user} (check the identity's role in the robot's zenoh.access)"


def _narrow_to_role(reply: dict[str, Any], t: Target) -> None:
    """``allowed`` is what the robot's state allows; shown to a monitor, only what a monitor may send."""
    allowed = _shown(reply_of(reply).allowed)
    if t.profile is not None and allowed is not None:
        reply["allowed"] = [v for v in allowed if role_may(t.profile.role, v)]


def _stranger(reply: Mapping[str, Any], robot: str) -> str:
    """A complaint when the reply came from another robot than the one named (two daemons, one id?)."""
    answered = _shown(reply_of(reply).robot_id)
    if answered is None:
        return f"the reply names no robot; expected {robot!r} (an older daemon?): not trusting it"
    if answered != robot:
        return f"robot {answered!r} answered, not {robot!r} as named: check the robot ids on this network"
    return ""


def _print_fleet(verb: str, replies: Sequence[dict[str, Any]], *, as_json: bool) -> int:
    views = sorted(((reply_of(r), r) for r in replies), key=lambda vr: _shown(vr[0].robot_id) or "")
    if as_json:
        print(json.dumps([r for _, r in views], indent=2))
    else:
        rows: list[tuple[str, ...]] = [
            ("robot", "ok", "state", "placed", "planned", "seen", "failed", "detail")
        ]
        for v, _ in views:
            counts = (v.mugs_placed, v.mugs_planned, v.mugs_total, v.mugs_failed)
            rows.append(
                (
                    _text(v.robot_id, "?"),
                    "yes" if v.ok else "no",
                    _text(v.state, "-"),
                    *(_text(n, "-") for n in counts),
                    "" if v.ok else _text(v.error, ""),
                )
            )
        widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
        for row in rows:
            print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
    return 0 if all(v.ok for v, _ in views) else 1


def _list(args: argparse.Namespace) -> int:
    t = target(args)
    try:
        with client_session(t) as session:
            robots = alive_robots(session, timeout_s=args.timeout)
    except Unreachable as e:
        print(f"dishbot list: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps({"endpoint": t.endpoint, "robots": robots}, indent=2))
    elif robots:
        print("\n".join(robots))
    else:
        print(f"dishbot list: no robot is alive at {t.endpoint}", file=sys.stderr)
    return 0 if robots else 1


def _start_body(args: argparse.Namespace) -> dict[str, object]:
    """The ``start`` payload; everything the client can check itself is checked here (exit 2)."""
    body: dict[str, object] = {}
    if args.dataset is not None:
        if not 1 <= args.dataset <= len(thesis.DATASETS):
            raise UsageError(f"--dataset {args.dataset}: choose a dataset 1-{len(thesis.DATASETS)}")
        body["dataset"] = args.dataset
    if args.mugs is not None:
        from cli.mugs_file import read_mugs_file

        body["mugs"] = read_mugs_file(args.mugs)
    if args.time_limit is not None and not 0.01 <= args.time_limit <= 600:
        raise UsageError(f"--time-limit {args.time_limit:g}: choose 0.01-600 seconds")
    _check_planner_names(args)
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


def _check_planner_names(args: argparse.Namespace) -> None:
    if args.method is None and args.cost is None and args.fitness is None:
        return
    # The planner's names live with the planner: imported only when a name needs checking.
    from daemon.config import PLANNER_COSTS, PLANNER_FITNESS
    from planning.placement import METHODS

    for flag, value, allowed in (
        ("--method", args.method, METHODS),
        ("--cost", args.cost, PLANNER_COSTS),
        ("--fitness", args.fitness, PLANNER_FITNESS),
    ):
        if value is not None and value not in allowed:
            raise UsageError(f"{flag} {value}: choose one of {', '.join(allowed)}")


def _readable(reply: Reply) -> str:
    lines = [f"robot: {_shown(reply.robot_id)}", f"state: {_shown(reply.state)}"]
    if _shown(reply.mugs_total) is not None:
        lines.append(
            f"mugs: {_shown(reply.mugs_placed)} placed of {_shown(reply.mugs_planned)} planned, "
            f"{reply.mugs_total} seen, {_shown(reply.mugs_failed)} failed; "
            f"current {_shown(reply.current_mug) or '-'}"
        )
    allowed = _shown(reply.allowed)
    if allowed is not None:
        lines.append(f"allowed: {', '.join(allowed)}")
    recording = _shown(reply.recording)
    if recording is not None and recording.ok is False:
        lines.append(
            f"recording: failed at {_shown(recording.path)}: {_shown(recording.error)}; "
            f"{_shown(recording.dropped)} messages lost"
        )
    return "\n".join(lines)


def _shown(value: T | UnsetType) -> T | None:
    """A reply's field as the client prints it (None when the reply leaves it out)."""
    from wire.messages import UnsetType

    return None if isinstance(value, UnsetType) else value


def _text(value: object, missing: str) -> str:
    from wire.messages import UnsetType

    return missing if isinstance(value, UnsetType) else str(value)


def reply_of(reply: Mapping[str, object]) -> Reply:
    """The reply as the wire contract declares it (imported when a reply came: ``--help`` loads no
    msgspec)."""
    from wire.messages import reply_of as declared

    return declared(reply)
