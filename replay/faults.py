"""Fault files, and the injector that makes their faults happen in a running daemon.

A fault file is TOML, a list of ``[[fault]]`` tables (the kinds and their fields are ``FAULT_KINDS``;
docs/recording.md has the table)::

    [[fault]]
    kind = "servo_overload"
    servo = 3
    at_state = "flip.turn"   # or at_s = 12.0 (simulated seconds from the session start)
    occurrence = 1           # the first time the state is entered (the default)
    after_s = 0.5
    duration_s = 2.0         # the overload lasts 2 s (without it: it trips once, latched until cleared)

``parse_faults`` validates a file strictly and says what is wrong in one line naming the entry and the
field (``UsageError``, which the CLI turns into exit 2). ``FaultInjector`` plugs into ``serve`` through its
hooks (``ServeHooks``): it schedules each fault on the daemon's clock, or on the ``occurrence``-th entry of a
state (seen in the ``transition`` events the daemon publishes), and makes it happen at the device boundary
or in the simulated world, never inside the job: the simulated servo chain sets its error bits and
registers, the FSR simulator goes quiet, the camera sends no frame, a mug really falls out of the gripper,
the recording's disk fills up, a Zenoh peer goes away. The daemon meets each one as it would on the robot.
Each firing is logged (``fault_injected``) and published on ``events`` (so recordings show it).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import re
import signal
import time
import tomllib
from collections.abc import Callable, Coroutine, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol

import structlog

from daemon.errors import UsageError
from drivers.sim.camera import CameraFault
from statechart.chart import LEAVES, STATES, top_level

if TYPE_CHECKING:
    import zenoh

    from daemon.app import RunOptions, ServeContext, ServeHooks
    from daemon.config import Config

log = structlog.get_logger("replay.faults")

_TRIGGER_KEYS: Final = ("at_s", "at_state", "occurrence", "after_s")
_COMMON_KEYS: Final = ("kind", *_TRIGGER_KEYS)
LOOP_STALL_DEFAULT_S: Final = 2.0
BUS_DEVICES: Final = ("servo", "fsr")


@dataclass(frozen=True, slots=True)
class KindSpec:
    """What a fault kind takes: its target and parameters, whether it lasts, and what it does."""

    target: str  # what it acts on, for the docs' table
    does: str  # what happens at the boundary, for the docs' table
    keys: tuple[str, ...] = ()  # further fields it takes
    required: tuple[str, ...] = ()
    lasts: bool = True  # takes duration_s
    default_duration: str = "for good"


FAULT_KINDS: Final[Mapping[str, KindSpec]] = {
    "servo_overload": KindSpec(
        "servo",
        "the servo's overload bit is set and its torque cut (1.0: Torque Limit 0; 2.0: Torque Enable 0, "
        "Hardware Error Status overload, alert flag); with duration_s it trips again whenever driven",
        ("servo", "duration_s"),
        ("servo",),
        default_duration="trips once; latched until the daemon clears it",
    ),
    "servo_overheat": KindSpec(
        "servo",
        "Present Temperature 5 °C above the Temperature Limit, overheating bit, torque cut (the factory "
        "Shutdown setting)",
        ("servo", "duration_s"),
        ("servo",),
        default_duration="hot until the end of the run (a reset cannot clear it while it lasts)",
    ),
    "servo_voltage": KindSpec(
        "servo",
        "Present Voltage 1 V below the Min Voltage Limit, input-voltage bit (1.0: in every status; 2.0: "
        "Hardware Error Status and alert until a reboot); the torque stays on",
        ("servo", "duration_s"),
        ("servo",),
    ),
    "servo_silent": KindSpec("servo", "the servo stops answering", ("servo", "duration_s"), ("servo",)),
    "bus_corrupt": KindSpec(
        "bus (optional servo)",
        "a seeded fraction `rate` of the status packets arrive with a bad checksum",
        ("rate", "servo", "seed", "duration_s"),
        ("rate",),
    ),
    "bus_unplug": KindSpec(
        'device = "servo" (default) or "fsr"',
        "the USB adapter is pulled (the port hangs up and cannot be opened), plugged back after duration_s",
        ("device", "duration_s"),
    ),
    "fsr_drop": KindSpec("FSR", "the Arduino reports zero force whatever the pad feels", ("duration_s",)),
    "fsr_spike": KindSpec(
        "FSR",
        "one sample of `value_n` newtons (default 0)",
        ("value_n",),
        lasts=False,
        default_duration="one sample",
    ),
    "fsr_silent": KindSpec("FSR", "the Arduino stops streaming", ("duration_s",)),
    "camera_no_frame": KindSpec(
        "camera",
        "each capture waits the frame timeout and fails as the RealSense driver does (CameraUnavailable)",
        ("duration_s",),
    ),
    "camera_stale": KindSpec("camera", "the last frame again, with its old time", ("duration_s",)),
    "camera_bad_frame": KindSpec(
        "camera", "frames without a valid depth pixel (NaN depth); the detector refuses them", ("duration_s",)
    ),
    "camera_hang": KindSpec("camera", "a capture does not return until the fault ends", ("duration_s",)),
    "mug_slip": KindSpec(
        "the carried mug",
        "the mug falls out of the gripper in the simulated world (nothing held: nothing happens)",
        lasts=False,
        default_duration="once",
    ),
    "mug_moved": KindSpec(
        "a counter mug (`mug`, default: the counter mug farthest from the gripper)",
        "the mug is moved by `dx_m`, `dy_m` on the counter in the simulated world",
        ("dx_m", "dy_m", "mug"),
        lasts=False,
        default_duration="once",
    ),
    "zenoh_peer_loss": KindSpec(
        "a Zenoh peer on loopback",
        "the peer the daemon connects to closes its session, and opens it again after duration_s",
        ("duration_s",),
    ),
    "disk_full": KindSpec(
        "the recording",
        "every write of the recording's files fails with ENOSPC (the file in progress stays cut; the next "
        "file opens once there is room)",
        ("duration_s",),
    ),
    "loop_stall": KindSpec(
        "the event loop",
        "the daemon's event loop is blocked for duration_s of wall time",
        ("duration_s",),
        default_duration=f"{LOOP_STALL_DEFAULT_S:g} s",
    ),
    "sigterm": KindSpec(
        "the process", "a real SIGTERM to the daemon's own process", lasts=False, default_duration="once"
    ),
}

SERVO_KINDS: Final = frozenset({"servo_overload", "servo_overheat", "servo_voltage", "servo_silent"})
CAMERA_KINDS: Final[Mapping[str, CameraFault]] = {
    "camera_no_frame": "no_frame",
    "camera_stale": "stale",
    "camera_bad_frame": "bad_frame",
    "camera_hang": "hang",
}
STATE_PATHS: Final = frozenset((*LEAVES, *(s.name for s in STATES)))
_FIELD_HELP: Final = {
    "servo": "the servo ID the fault acts on",
    "rate": "the fraction of status packets corrupted, in (0, 1]",
    "kind": f"one of {', '.join(FAULT_KINDS)}",
}


@dataclass(frozen=True, slots=True)
class FaultSpec:
    """One ``[[fault]]`` entry, validated; ``index`` is its place in the file (1-based)."""

    index: int
    kind: str
    at_s: float | None = None
    at_state: str | None = None
    occurrence: int = 1
    after_s: float = 0.0
    duration_s: float | None = None
    servo: int | None = None
    rate: float | None = None
    seed: int | None = None
    value_n: float | None = None
    dx_m: float | None = None
    dy_m: float | None = None
    mug: str | None = None
    device: str | None = None

    def to_json(self) -> dict[str, object]:
        """The entry as its file states it (defaults included, unset fields left out)."""
        out: dict[str, object] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None or (f.name == "occurrence" and self.at_state is None):
                continue
            if f.name == "after_s" and self.at_state is None:
                continue
            out[f.name] = value
        return out

    @property
    def trigger(self) -> str:
        """``at 12.0 s`` or ``at flip.turn #2 + 0.5 s``, for messages."""
        if self.at_state is None:
            return f"at {self.at_s:g} s"
        text = f"at {self.at_state}"
        if self.occurrence != 1:
            text += f" #{self.occurrence}"
        if self.after_s:
            text += f" + {self.after_s:g} s"
        return text


def load_fault_file(path: Path, *, config: Config | None = None) -> tuple[FaultSpec, ...]:
    """The faults of the file at ``path`` (``parse_faults``); ``UsageError`` when it cannot be read."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"{path}: no such fault file") from None
    except (OSError, UnicodeDecodeError) as e:
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise UsageError(f"{path}: cannot read the fault file: {reason}") from e
    return parse_faults(text, source=str(path), config=config)


def parse_faults(text: str, *, source: str, config: Config | None = None) -> tuple[FaultSpec, ...]:
    """The faults a fault file's ``text`` lists, validated; ``UsageError`` with one line naming the entry
    and the field (``source`` names the file). With ``config``, servo IDs must be in its chain."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise UsageError(f"{source}: {_toml_error(str(e))}") from None
    extra = sorted(set(document) - {"fault"})
    if extra:
        raise UsageError(f"{source}: {extra[0]}: unknown key (a fault file holds only [[fault]] tables)")
    entries = document.get("fault")
    if entries is None:
        raise UsageError(f"{source}: no [[fault]] table; list the faults as [[fault]] tables")
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise UsageError(f"{source}: fault: must be a list of [[fault]] tables")
    servos = _configured_servos(config)
    return tuple(_entry(i, entry, source, servos) for i, entry in enumerate(entries, start=1))


def dump_faults(faults: Sequence[FaultSpec]) -> str:
    """A fault file listing ``faults`` (``parse_faults`` reads it back to the same entries)."""
    blocks = []
    for spec in faults:
        lines = ["[[fault]]"]
        for key, value in spec.to_json().items():
            if key != "index":
                lines.append(f"{key} = {_toml_value(value)}")
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks) + "\n"


def _toml_value(value: object) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _toml_error(message: str) -> str:
    found = re.search(r"\(at line (\d+), column (\d+)\)", message)
    what = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", message)
    if found is None:
        return f"not valid TOML: {what}"
    return f"line {found.group(1)}: not valid TOML: {what}"


def _configured_servos(config: Config | None) -> tuple[int, ...] | None:
    if config is None:
        return None
    return tuple(s.id for s in config.hardware.servos)


class _Entry:
    """Reads one table, raising the one-line error for the first thing wrong."""

    def __init__(self, index: int, table: Mapping[str, Any], source: str) -> None:
        self.index = index
        self.table = table
        self.source = source
        self.kind: str | None = None

    def error(self, key: str, problem: str) -> UsageError:
        kind = f" ({self.kind})" if self.kind is not None else ""
        return UsageError(f"{self.source}: fault {self.index}{kind}: {key}: {problem}")

    def number(
        self, key: str, *, minimum: float = 0.0, strict: bool = False, unit: str = "s"
    ) -> float | None:
        value = self.table.get(key)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"must be a number{f' ({unit})' if unit else ''}, got {_shown(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value}")
        if value < minimum or (strict and value == minimum):
            bound = f"greater than {minimum:g}" if strict else f"at least {minimum:g}"
            raise self.error(key, f"must be {bound}{f' {unit}' if unit else ''}, got {value:g}")
        return value

    def real(self, key: str) -> float | None:
        value = self.table.get(key)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.error(key, f"must be a finite number (metres), got {_shown(value)}")
        return float(value)

    def integer(self, key: str, *, minimum: int) -> int | None:
        value = self.table.get(key)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {_shown(value)}")
        if value < minimum:
            raise self.error(key, f"must be at least {minimum}, got {value}")
        return value

    def text(self, key: str) -> str | None:
        value = self.table.get(key)
        if value is None:
            return None
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a non-empty string, got {_shown(value)}")
        return value


def _shown(value: object) -> str:
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return repr(value)


def _entry(index: int, table: Mapping[str, Any], source: str, servos: tuple[int, ...] | None) -> FaultSpec:
    e = _Entry(index, table, source)
    kind = table.get("kind")
    if kind is None:
        raise e.error("kind", f"missing ({_FIELD_HELP['kind']})")
    if not isinstance(kind, str):
        raise e.error("kind", f"must be a string, got {_shown(kind)}")
    spec = FAULT_KINDS.get(kind)
    if spec is None:
        raise e.error("kind", f"unknown kind {kind!r} ({_FIELD_HELP['kind']})")
    e.kind = kind
    allowed = (*_COMMON_KEYS, *spec.keys)
    for key in table:
        if key not in allowed:
            if key == "duration_s":
                raise e.error(key, f"{kind} happens once; it takes no duration")
            raise e.error(key, f"unknown key (allowed: {', '.join(allowed)})")
    for key in spec.required:
        if key not in table:
            raise e.error(key, f"missing ({_FIELD_HELP.get(key, key)})")
    at_s = e.number("at_s")
    at_state = e.text("at_state")
    if at_s is None and at_state is None:
        raise e.error("at_s", "missing: give at_s (simulated seconds from the session start) or at_state")
    if at_s is not None and at_state is not None:
        raise e.error("at_state", "give either at_s or at_state, not both")
    if at_state is not None and at_state not in STATE_PATHS:
        raise e.error(
            "at_state",
            f"{at_state!r} is not a state of the chart (e.g. detect, flip, flip.turn, place.release)",
        )
    occurrence = e.integer("occurrence", minimum=1)
    after_s = e.number("after_s")
    if at_state is None:
        for key in ("occurrence", "after_s"):
            if key in table:
                raise e.error(key, "only with at_state (at_s already says when)")
    duration_s = e.number("duration_s", strict=True)
    if kind == "loop_stall" and duration_s is None:
        duration_s = LOOP_STALL_DEFAULT_S
    servo = e.integer("servo", minimum=0)
    if servo is not None:
        if servo > 253:
            raise e.error("servo", f"must be a servo ID 0-253, got {servo}")
        if servos is not None and servo not in servos:
            raise e.error(
                "servo", f"no servo {servo} in the configured chain ({', '.join(map(str, servos))})"
            )
    rate = e.number("rate", strict=True, unit="")
    if rate is not None and rate > 1.0:
        raise e.error("rate", f"must be in (0, 1], got {rate:g}")
    device = e.text("device")
    if kind == "bus_unplug":
        device = device or "servo"
        if device not in BUS_DEVICES:
            raise e.error("device", f"must be {' or '.join(map(repr, BUS_DEVICES))}, got {device!r}")
    value_n = e.real("value_n")
    if value_n is not None and value_n < 0:
        raise e.error("value_n", f"must be at least 0 N, got {value_n:g}")
    if kind == "fsr_spike" and value_n is None:
        value_n = 0.0
    dx_m, dy_m = e.real("dx_m"), e.real("dy_m")
    if kind == "mug_moved" and not (dx_m or dy_m):
        raise e.error("dx_m", "missing: say how far to move the mug (dx_m, dy_m in metres, not both 0)")
    if kind == "mug_moved":
        dx_m, dy_m = dx_m or 0.0, dy_m or 0.0
    seed = e.integer("seed", minimum=0)
    if kind == "bus_corrupt" and seed is None:
        seed = 0
    return FaultSpec(
        index=index,
        kind=kind,
        at_s=at_s,
        at_state=at_state,
        occurrence=occurrence or 1,
        after_s=after_s or 0.0,
        duration_s=duration_s,
        servo=servo,
        rate=rate,
        seed=seed,
        value_n=value_n,
        dx_m=dx_m,
        dy_m=dy_m,
        mug=e.text("mug"),
        device=device,
    )


# --- making faults happen ---------------------------------------------------------------------------------

End = Callable[[], None]


class Cell(Protocol):
    """Where the faults of one simulated cell act; each returns how to end a lasting fault (None: it needs no
    ending) and what it acted on, for the report."""

    name: str

    def servo_ids(self) -> tuple[int, ...]: ...

    def act(self, spec: FaultSpec) -> tuple[End | None, dict[str, object]]: ...


class FaultInjector:
    """Makes ``faults`` happen in a running daemon (plug ``hooks()`` into ``serve``).

    ``on_fire`` is called with each fault just before it takes effect. ``fired`` lists what happened:
    ``{"kind", "fired_at_s", "index", ...target}`` and ``ended_at_s`` once a lasting fault ends. Faults are
    timed on the daemon's clock from ``attach`` (the session's start). A fault the cell cannot have is refused
    at ``attach`` with one line naming it (``UsageError``).
    """

    def __init__(
        self, faults: Sequence[FaultSpec], *, on_fire: Callable[[FaultSpec], None] | None = None
    ) -> None:
        self.faults = tuple(faults)
        self.on_fire = on_fire
        self.fired: list[dict[str, object]] = []
        self._ctx: ServeContext | None = None
        self._cell: Cell | None = None
        self._t0 = 0.0
        self._entries: dict[str, int] = {}
        self._waiting = [f for f in self.faults if f.at_state is not None]
        self._tasks: set[asyncio.Task[None]] = set()
        self._peer: _LoopbackPeer | None = None
        self._ends: list[End] = []

    # --- wiring --------------------------------------------------------------------------------------------

    def prepare(self, options: RunOptions) -> RunOptions:
        """``options`` with what the faults need before the daemon starts: for ``zenoh_peer_loss``, a Zenoh
        peer on a free loopback port that the daemon connects to (and later loses)."""
        if not any(f.kind == "zenoh_peer_loss" for f in self.faults):
            return options
        if self._peer is None:
            self._peer = _LoopbackPeer()
            self._peer.open()
        return replace(options, connect=(*options.connect, self._peer.endpoint))

    def hooks(self) -> ServeHooks:
        """The hooks for ``serve``: ``attach`` when ready, ``on_publish`` for every message."""
        from daemon.app import ServeHooks

        return ServeHooks(on_publish=(self.on_publish,), on_ready=self.attach)

    def attach(self, ctx: ServeContext) -> None:
        """The daemon is ready: find what each fault acts on, refuse the ones the cell cannot have, and
        schedule the timed ones."""
        self._ctx = ctx
        self._cell = cell_of(ctx)
        for spec in self.faults:
            self._check(spec)
        self._t0 = ctx.clock.monotonic()
        for spec in self.faults:
            if spec.at_s is not None:
                self._spawn(self._fire_at(spec, self._t0 + spec.at_s))

    def on_publish(self, topic: str, payload: Mapping[str, object]) -> None:
        """Count state entries (``transition`` events on ``events``) for the ``at_state`` faults."""
        if topic != "events" or payload.get("kind") != "transition" or self._ctx is None:
            return
        dest = str(payload.get("dest", ""))
        source = str(payload.get("source", ""))
        entered = {dest}
        if top_level(source) != top_level(dest) or source == dest:
            entered.add(top_level(dest))
        for path in entered:
            self._entries[path] = self._entries.get(path, 0) + 1
        for spec in list(self._waiting):
            assert spec.at_state is not None
            if spec.at_state in entered and self._entries[spec.at_state] == spec.occurrence:
                self._waiting.remove(spec)
                if spec.after_s == 0.0:
                    self._fire(spec)
                else:
                    self._spawn(self._fire_at(spec, self._ctx.clock.monotonic() + spec.after_s))

    def close(self) -> None:
        """End every fault still on (a replugged bus, a freed disk) and close the loopback peer."""
        for task in self._tasks:
            task.cancel()
        for end in self._ends:
            with contextlib.suppress(Exception):
                end()
        self._ends.clear()
        if self._peer is not None:
            self._peer.close()
            self._peer = None

    # --- firing --------------------------------------------------------------------------------------------

    def _check(self, spec: FaultSpec) -> None:
        cell = self._cell
        ctx = self._ctx
        assert ctx is not None
        where = f"fault {spec.index} ({spec.kind})"
        if spec.kind in _CELL_KINDS and cell is None:
            raise UsageError(
                f"{where}: the {ctx.backend.name} backend has no simulated devices or world to fail; fault "
                "files run on the simulated cell (--sim)"
            )
        if cell is not None and spec.servo is not None and spec.servo not in cell.servo_ids():
            chain = ", ".join(map(str, cell.servo_ids()))
            raise UsageError(
                f"{where}: servo: no servo {spec.servo} in the {cell.name} cell's chain ({chain})"
            )
        if spec.kind == "zenoh_peer_loss" and self._peer is None:
            raise UsageError(
                f"{where}: the daemon has no peer to lose; call FaultInjector.prepare(options) before serve"
            )

    def _spawn(self, work: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _fire_at(self, spec: FaultSpec, t: float) -> None:
        ctx = self._ctx
        assert ctx is not None
        await ctx.clock.sleep_until(t)
        self._fire(spec)

    def _fire(self, spec: FaultSpec) -> None:
        """Make ``spec`` happen now, on the loop (before anything else runs: a fault due as a state is
        entered is there before the state's work starts)."""
        ctx = self._ctx
        assert ctx is not None
        if self.on_fire is not None:
            self.on_fire(spec)
        fired_at = round(ctx.clock.monotonic() - self._t0, 3)
        record: dict[str, object] = {"kind": spec.kind, "fired_at_s": fired_at, "index": spec.index}
        end, target = self._act(spec)
        record.update(target)
        self.fired.append(record)
        self._report(record)
        if end is None:
            return
        self._ends.append(end)
        if spec.duration_s is not None and spec.kind != "loop_stall":
            self._spawn(self._end_after(spec, record, end))

    def _report(self, record: Mapping[str, object]) -> None:
        """Log the firing (``fault_injected``, also published on ``log``) and publish it on ``events``."""
        ctx = self._ctx
        assert ctx is not None
        detail = {k: v for k, v in record.items() if k != "kind"}
        state = ctx.job.chart.state
        log.warning("fault_injected", fault=record["kind"], state=state, **detail)
        event = {
            **detail,
            "kind": "fault_injected",
            "fault": record["kind"],
            "state": state,
            "t": ctx.clock.now(),
        }
        ctx.session.publish("events", event)

    async def _end_after(self, spec: FaultSpec, record: dict[str, object], end: End) -> None:
        ctx = self._ctx
        assert ctx is not None
        assert spec.duration_s is not None
        await ctx.clock.sleep(spec.duration_s)
        if end in self._ends:
            self._ends.remove(end)
        if spec.kind == "zenoh_peer_loss" and self._peer is not None:
            await asyncio.to_thread(self._peer.open)
        else:
            end()
        record["ended_at_s"] = round(ctx.clock.monotonic() - self._t0, 3)
        log.info("fault_ended", fault=spec.kind, index=spec.index, ended_at_s=record["ended_at_s"])
        ctx.session.publish(
            "events",
            {
                "kind": "fault_ended",
                "fault": spec.kind,
                "index": spec.index,
                "ended_at_s": record["ended_at_s"],
                "state": ctx.job.chart.state,
                "t": ctx.clock.now(),
            },
        )

    def _act(self, spec: FaultSpec) -> tuple[End | None, dict[str, object]]:
        ctx = self._ctx
        assert ctx is not None
        kind = spec.kind
        if kind == "sigterm":
            os.kill(os.getpid(), signal.SIGTERM)
            return None, {}
        if kind == "loop_stall":
            assert spec.duration_s is not None
            _stall(spec.duration_s)
            return None, {"stalled_s": spec.duration_s}
        if kind == "disk_full":
            disk = ctx.recording.disk
            clock = ctx.clock
            disk.fill(_log_time_ns(clock.now()))
            return (lambda: disk.free(_log_time_ns(clock.now()))), {}
        if kind == "zenoh_peer_loss":
            peer = self._peer
            assert peer is not None
            # Closing a Zenoh session blocks until its links are down: off the loop.
            self._spawn(asyncio.to_thread(peer.close))
            return peer.close, {"peer": peer.endpoint}
        assert self._cell is not None
        return self._cell.act(spec)


_CELL_KINDS: Final = frozenset(FAULT_KINDS) - {"sigterm", "loop_stall", "disk_full", "zenoh_peer_loss"}


def _log_time_ns(t: float) -> int:
    """A recording's log time for the clock's ``now()`` (as ``serve`` stamps every message)."""
    return round(t * 1e9)


def _stall(seconds: float) -> None:
    """Block the event loop for ``seconds`` of wall time (the ``loop_stall`` fault does it on purpose)."""
    time.sleep(seconds)


class _LoopbackPeer:
    """A Zenoh peer listening on a free loopback port (multicast scouting off), for the daemon to connect
    to and lose."""

    def __init__(self) -> None:
        import socket

        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            port: int = s.getsockname()[1]
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self._session: zenoh.Session | None = None

    def open(self) -> None:
        import zenoh

        from daemon.zenoh_session import session_config

        if self._session is None:
            self._session = zenoh.open(session_config(listen=[self.endpoint], connect=[]))

    def close(self) -> None:
        session, self._session = self._session, None
        if session is not None:
            session.close()  # type: ignore[no-untyped-call]


def cell_of(ctx: ServeContext) -> Cell | None:
    """Where faults act in the daemon's backend: the kinematic or the MuJoCo cell (None: real hardware)."""
    from daemon.sim_backend import KinematicCounter, MujocoCounter

    counter = ctx.backend.counter
    if isinstance(counter, KinematicCounter):
        from replay.cells import KinematicFaultCell

        return KinematicFaultCell(counter)
    if isinstance(counter, MujocoCounter):
        from replay.cells import MujocoFaultCell

        return MujocoFaultCell(counter)
    return None


__all__ = [
    "CAMERA_KINDS",
    "FAULT_KINDS",
    "SERVO_KINDS",
    "Cell",
    "FaultInjector",
    "FaultSpec",
    "KindSpec",
    "dump_faults",
    "load_fault_file",
    "parse_faults",
]
