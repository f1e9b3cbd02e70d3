"""``dishbot monitor``: live state, joints and gripper force of a running daemon, in the terminal.

Subscribes to ``state``, ``joints``, ``gripper`` and ``events`` of one robot and redraws a small panel a few
times per second (on a terminal), or prints one line per state change and event (when piped).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

from daemon.commands.client import DEFAULT_ENDPOINT
from daemon.config import check_endpoint
from daemon.errors import ConfigError, UsageError

if TYPE_CHECKING:
    import zenoh


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "monitor",
        help="show a running daemon's live state, joints and gripper force",
        description="Show a running daemon's state, joint angles, gripper force and events as they happen.",
    )
    parser.add_argument(
        "--connect",
        default=DEFAULT_ENDPOINT,
        metavar="ENDPOINT",
        help=f"daemon endpoint (default {DEFAULT_ENDPOINT})",
    )
    parser.add_argument("--robot", default="dishbot", metavar="ID", help="robot id (default dishbot)")
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
    parser.set_defaults(handler=_monitor)


class _Latest:
    """The newest sample of each topic, filled by Zenoh's threads and read by the drawing loop."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.values: dict[str, dict[str, Any]] = {}
        self.lines: list[str] = []
        self.last_state: str | None = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        topic = str(sample.key_expr).rsplit("/", 1)[-1]
        try:
            payload = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        with self.lock:
            self.values[topic] = payload
            if topic == "state" and payload.get("state") != self.last_state:
                self.last_state = payload.get("state")
                self.lines.append(f"state {self.last_state}  placed {payload.get('mugs_placed')}")
            elif topic == "events" and payload.get("kind") != "transition":
                detail = {k: v for k, v in payload.items() if k not in ("kind", "t", "state")}
                self.lines.append(f"event {payload.get('kind')} {json.dumps(detail)}")


def _monitor(args: argparse.Namespace) -> int:
    import zenoh

    from daemon.zenoh_session import key, session_config

    try:
        endpoint = check_endpoint(args.connect, "--connect")
    except ConfigError as e:
        raise UsageError(str(e)) from e
    if not 0.2 <= args.rate <= 50:
        raise UsageError(f"--rate {args.rate:g}: choose 0.2-50 redraws per second")
    latest = _Latest()
    tty = sys.stdout.isatty()
    deadline = None if args.duration is None else time.monotonic() + args.duration
    with zenoh.open(session_config(listen=[], connect=[endpoint])) as session:
        subscribers = [  # kept referenced for the session's lifetime; closing it undeclares them
            session.declare_subscriber(key(args.robot, topic), latest.on_sample)
            for topic in ("state", "joints", "gripper", "events")
        ]
        try:
            while deadline is None or time.monotonic() < deadline:
                time.sleep(1.0 / args.rate)
                with latest.lock:
                    lines, latest.lines = latest.lines, []
                    values = dict(latest.values)
                if tty:
                    sys.stdout.write("\x1b[2J\x1b[H" + panel(values, args.robot, endpoint) + "\n")
                    sys.stdout.writelines(line + "\n" for line in lines[-5:])
                else:
                    sys.stdout.writelines(line + "\n" for line in lines)
                sys.stdout.flush()
        except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C, or the reader (e.g. head) went away
            pass
        del subscribers
    return 0


def panel(values: dict[str, dict[str, Any]], robot: str, endpoint: str) -> str:
    """The monitor's text panel for the newest state, joints and gripper samples."""
    state = values.get("state", {})
    joints = values.get("joints", {})
    gripper = values.get("gripper", {})
    lines = [f"dishbot {robot} @ {endpoint}"]
    if not state:
        lines.append("waiting for the daemon ...")
        return "\n".join(lines)
    lines.append(
        f"state   {state.get('state')}   mug {state.get('current_mug') or '-'}   "
        f"placed {state.get('mugs_placed')}/{state.get('mugs_planned')}  seen {state.get('mugs_total')}  "
        f"failed {state.get('mugs_failed')}"
    )
    names = joints.get("names", [])
    positions = joints.get("position_rad", [])
    if names:
        lines.append("joints  " + "  ".join(f"{n} {p:+.3f}" for n, p in zip(names, positions, strict=False)))
    if gripper:
        force = gripper.get("force_n")
        force_text = "-" if force is None else f"{force:.2f} N"
        lines.append(
            f"gripper aperture {gripper.get('aperture_m', 0.0) * 1000:.1f} mm  force {force_text}  "
            f"{'holding' if gripper.get('holding') else 'empty'}"
        )
    return "\n".join(lines)
