"""``dishbot monitor``: live state, joints and gripper force of running daemons, in the terminal.

Subscribes to ``state``, ``joints``, ``gripper`` and ``events`` of one robot (or every robot with
``--robot '*'``) and to their liveliness tokens, and redraws a panel a few times per second on a terminal
(80 columns), or prints one line per state change, event and arrival or departure when piped. A robot whose
token drops is shown as gone, with the time it went and its last state, rather than as if it were still in
that state. The last events stay on screen. When the endpoint cannot be reached the monitor says why and
keeps trying; Zenoh reconnects it after a lost link.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final, TypeVar

from cli.commands.client import Target, Unreachable, add_target_flags, client_session, target
from daemon.errors import UsageError
from wire.messages import Gripper, Joints, Message, State, UnsetType

T = TypeVar("T")

# The topics the panel shows, newest sample each, as their declared messages.
_SHOWN: Final[dict[str, type[Message]]] = {"state": State, "joints": Joints, "gripper": Gripper}

# Zenoh is imported when the verb runs: `dishbot monitor --help` loads none of it.
if TYPE_CHECKING:
    import zenoh

WIDTH = 80
EVENTS_SHOWN = 8
_TOPICS = ("state", "joints", "gripper", "events")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "monitor",
        help="show running daemons' live state, joints and gripper force",
        description=(
            "Show a running daemon's state, joint angles, gripper force and events as they happen; "
            "--robot '*' shows every robot at the endpoint. A daemon that goes away is shown as gone."
        ),
    )
    add_target_flags(parser, many=True)
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="exit after S seconds (default: until Ctrl-C)",
    )
    parser.add_argument(
        "--rate", type=float, default=5.0, metavar="HZ", help="panel redraws per second (default 5)"
    )
    parser.set_defaults(handler=_monitor, timeout=5.0)


@dataclass
class RobotView:
    """What the monitor knows of one robot: newest samples, and whether its liveliness token is there."""

    values: dict[str, Message] = field(default_factory=dict)  # the newest state, joints and gripper
    alive: bool | None = None  # None: no token seen either way yet
    changed_at: float | None = None  # wall time the token last appeared or dropped
    last_state: str | None = None


class Watch:
    """Filled by Zenoh's threads (samples, liveliness), read by the drawing loop under ``lock``."""

    def __init__(self, *, many: bool) -> None:
        self.lock = threading.Lock()
        self.many = many
        self.robots: dict[str, RobotView] = {}
        self.events: deque[str] = deque(maxlen=EVENTS_SHOWN)  # kept on screen
        self.lines: list[str] = []  # not yet printed (pipe mode)

    def robot(self, robot_id: str) -> RobotView:
        return self.robots.setdefault(robot_id, RobotView())

    def on_sample(self, sample: zenoh.Sample) -> None:
        from wire.messages import BadMessage, Event, decode

        _, robot_id, topic = str(sample.key_expr).split("/", 2)
        data = sample.payload.to_bytes()
        kind = _SHOWN.get(topic)
        try:
            message = decode(data, kind, name=topic) if kind is not None else None
            event = decode(data, Event, name=topic) if topic == "events" else None
        except BadMessage:  # not what the topic carries: nothing to show of it
            return
        with self.lock:
            view = self.robot(robot_id)
            if message is not None:
                view.values[topic] = message
            if isinstance(message, State) and message.state != view.last_state:
                view.last_state = message.state
                self.add_line(robot_id, f"state {message.state}  placed {message.mugs_placed}", False)
            elif event is not None and event.kind != "transition":
                payload = json.loads(data)  # every key of the event, declared or not
                detail = {k: v for k, v in payload.items() if k not in ("kind", "t", "state")}
                self.add_line(robot_id, f"event {event.kind} {json.dumps(detail)}", True)

    def on_alive(self, sample: zenoh.Sample) -> None:
        robot_id = str(sample.key_expr).split("/")[1]
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        with self.lock:
            view = self.robot(robot_id)
            if view.alive == alive:
                return
            first = view.alive is None
            view.alive, view.changed_at = alive, time.time()
            if alive and first:
                return
            what = "back (liveliness token)" if alive else "gone (liveliness token dropped)"
            self.add_line(robot_id, f"daemon {what}", True)

    def add_line(self, robot_id: str, text: str, keep: bool) -> None:
        line = f"{robot_id}: {text}" if self.many else text
        self.lines.append(line)
        if keep:
            self.events.append(f"{time.strftime('%H:%M:%S')} {line}")


def _monitor(args: argparse.Namespace) -> int:
    if not 0.2 <= args.rate <= 50:
        raise UsageError(f"--rate {args.rate:g}: choose 0.2-50 redraws per second")
    if args.duration is not None and args.duration <= 0:
        raise UsageError(f"--duration {args.duration:g}: choose a positive number of seconds")
    t = target(args, many=True)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    tty = sys.stdout.isatty()
    said = ""
    try:
        while deadline is None or time.monotonic() < deadline:
            try:
                with client_session(t) as session:
                    _watch(session, t, args.rate, deadline, tty)
                return 0
            except Unreachable as e:  # not there yet: say why (once, when piped), keep trying
                if tty or str(e) != said:
                    _show(tty, [f"dishbot monitor: {e}; retrying"])
                said = str(e)
                time.sleep(1.0 if deadline is None else max(0.0, min(1.0, deadline - time.monotonic())))
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C, or the reader (e.g. head) went away
        pass
    return 0


def _watch(session: zenoh.Session, t: Target, rate: float, deadline: float | None, tty: bool) -> None:
    from daemon.zenoh_session import key

    watch = Watch(many=t.many)
    subscribers = [  # kept referenced for the session's lifetime; closing it undeclares them
        session.declare_subscriber(key(t.robot, topic), watch.on_sample) for topic in _TOPICS
    ]
    subscribers.append(
        session.liveliness().declare_subscriber(key(t.robot, "alive"), watch.on_alive, history=True)
    )
    while deadline is None or time.monotonic() < deadline:
        time.sleep(1.0 / rate)
        linked = bool(session.info.peers_zid() or session.info.routers_zid())
        with watch.lock:
            lines, watch.lines = watch.lines, []
            text = screen(watch, t, linked=linked) if tty else ""
        if tty:
            sys.stdout.write("\x1b[2J\x1b[H" + text + "\n")
            sys.stdout.flush()
        else:
            _show(False, lines)
    del subscribers


def _show(tty: bool, lines: Sequence[str]) -> None:
    """On a terminal: a fresh screen of lines cut to 80 columns; piped: the lines whole, for whoever reads."""
    if tty:
        sys.stdout.write("\x1b[2J\x1b[H")
    sys.stdout.writelines((fit(line) if tty else line) + "\n" for line in lines)
    sys.stdout.flush()


def screen(watch: Watch, t: Target, *, linked: bool) -> str:
    """The whole terminal screen: one robot's panel (or a line per robot), then the last events."""
    if t.many:
        lines = [f"dishbot robots @ {t.endpoint}" + ("" if linked else "  (link down, reconnecting)")]
        if not watch.robots:
            lines.append("waiting for robots ...")
        lines += [robot_line(robot_id, watch.robots[robot_id]) for robot_id in sorted(watch.robots)]
    else:
        view = watch.robots.get(t.robot, RobotView())
        lines = panel(view.values, t.robot, t.endpoint, alive=view.alive, since=view.changed_at).splitlines()
        if not linked:
            lines.insert(1, "link down: reconnecting ...")
    if watch.events:
        lines += ["", "recent events:", *watch.events]
    return "\n".join(fit(line) for line in lines)


def panel(
    values: Mapping[str, Message],
    robot: str,
    endpoint: str,
    *,
    alive: bool | None = True,
    since: float | None = None,
) -> str:
    """The monitor's text panel for one robot's newest state, joints and gripper samples (≤ 80 columns)."""
    state, joints, gripper = values.get("state"), values.get("joints"), values.get("gripper")
    lines = [f"dishbot {robot} @ {endpoint}"]
    if alive is False:
        when = "" if since is None else f" at {time.strftime('%H:%M:%S', time.localtime(since))}"
        lines.append(f"daemon GONE{when}: its liveliness token dropped")
        if isinstance(state, State):
            lines.append(f"last state {state.state} (no longer current)")
        return "\n".join(fit(line) for line in lines)
    if not isinstance(state, State):
        lines.append("waiting for the daemon ...")
        return "\n".join(lines)
    lines.append(
        f"state   {state.state}   mug {_shown(state.current_mug) or '-'}   "
        f"placed {state.mugs_placed}/{_shown(state.mugs_planned)}  seen {state.mugs_total}  "
        f"failed {_shown(state.mugs_failed)}"
    )
    if isinstance(joints, Joints) and joints.names:
        cells = [f"{n} {p:+.3f}" for n, p in zip(joints.names, joints.position_rad, strict=False)]
        lines += wrapped("joints  ", cells)
    if isinstance(gripper, Gripper):
        force = _shown(gripper.force_n)
        force_text = "-" if force is None else f"{force:.2f} N"
        lines.append(
            f"gripper aperture {gripper.aperture_m * 1000:.1f} mm  force {force_text}  "
            f"{'holding' if gripper.holding else 'empty'}"
        )
    return "\n".join(fit(line) for line in lines)


def robot_line(robot_id: str, view: RobotView) -> str:
    """One robot in the fleet view."""
    state = view.values.get("state")
    if view.alive is False:
        return f"{robot_id:<12} GONE  last state {state.state if isinstance(state, State) else '-'}"
    if not isinstance(state, State):
        return f"{robot_id:<12} alive, no state yet"
    return (
        f"{robot_id:<12} {state.state}  placed {state.mugs_placed}/{_shown(state.mugs_planned)}"
        f"  failed {_shown(state.mugs_failed)}  mug {_shown(state.current_mug) or '-'}"
    )


def _shown(value: T | UnsetType) -> T | None:
    """A field the message may leave out, as the panel shows it (None when left out)."""
    return None if isinstance(value, UnsetType) else value


def wrapped(prefix: str, cells: Sequence[str]) -> list[str]:
    """``cells`` after ``prefix``, two spaces apart, wrapped to ``WIDTH`` columns under the first cell."""
    lines: list[str] = []
    current, empty = prefix, True
    for cell in cells:
        if not empty and len(current) + 2 + len(cell) > WIDTH:
            lines.append(current)
            current, empty = " " * len(prefix), True
        current += ("" if empty else "  ") + cell
        empty = False
    lines.append(current)
    return lines


def fit(line: str) -> str:
    """``line`` cut to ``WIDTH`` columns (an ellipsis marks the cut)."""
    return line if len(line) <= WIDTH else line[: WIDTH - 1] + "…"
