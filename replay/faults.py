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
import threading
import time
import tomllib
from collections.abc import Callable, Coroutine, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Final

import msgspec
import structlog

from daemon.errors import UsageError
from drivers.sim.camera import CameraFaultKind
from statechart.chart import LEAVES, STATES, top_level
from validation import OneOf, above, convert, show, toml, within
from wire.messages import BadMessage, Detections, Event
from wire.messages import convert as as_message

if TYPE_CHECKING:
    import zenoh

    from daemon.app import RunOptions, ServeContext, ServeHooks
    from daemon.config import Config
    from replay.cells import FaultCell

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
        "the peer the daemon connects to closes its session, and opens it again after duration_s of wall "
        "time (Zenoh notices a lost link on the wall clock)",
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
# The kinds that act on the daemon's recording itself (its disk): a replay with one of them must write the
# recording it would otherwise not keep.
RECORDING_KINDS: Final = frozenset(k for k, spec in FAULT_KINDS.items() if spec.target == "the recording")
CAMERA_KINDS: Final[Mapping[str, CameraFaultKind]] = {
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


DAY_S: Final = 86_400.0
# Every number a fault file can hold, with the values it may take (docs/recording.md lists them), declared
# once for the one validator (``validation.convert``).
Seconds = Annotated[float, within(0.0, DAY_S, unit="s")]
Duration = Annotated[float, above(0.0, DAY_S, unit="s")]
# A loop_stall blocks the event loop for its duration of wall time: at most a minute (past WatchdogSec,
# systemd has long restarted the daemon).
LOOP_STALL_MAX_S: Final = 60.0
Name = Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
Move = Annotated[float, within(-1.0, 1.0, unit="m")]


@dataclass(frozen=True, slots=True)
class _FaultTable:
    """One ``[[fault]]`` table as the file holds it; which keys a kind takes is ``FAULT_KINDS``."""

    kind: Annotated[str, OneOf(tuple(FAULT_KINDS))]
    at_s: Seconds | None = None
    at_state: Name | None = None
    occurrence: Annotated[int, within(1, 10_000)] | None = None
    after_s: Seconds | None = None
    duration_s: Duration | None = None
    servo: Annotated[int, within(0, 253)] | None = None
    rate: Annotated[float, above(0.0, 1.0)] | None = None
    seed: Annotated[int, within(0, 2**32 - 1)] | None = None
    value_n: Annotated[float, within(0.0, 1000.0, unit="N")] | None = None
    dx_m: Move | None = None
    dy_m: Move | None = None
    mug: Name | None = None
    device: Annotated[str, OneOf(BUS_DEVICES)] | None = None


# A loop_stall's duration, whose range is its own (``LOOP_STALL_MAX_S``).
StallDuration = Annotated[float, above(0.0, LOOP_STALL_MAX_S, unit="s")]


@dataclass(frozen=True)
class _LoopStallTable(_FaultTable):
    """A ``loop_stall`` table: the common shape with the stall's own range for ``duration_s``."""

    duration_s: StallDuration | None = None


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
    # A fault file is its own document (not a wire message): read here and in ``_entry`` by its own validator,
    # whose one-line errors name the file, the entry and the key.
    entries = document.get("fault")
    if entries is None:
        raise UsageError(f"{source}: no [[fault]] table; list the faults as [[fault]] tables")
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise UsageError(f"{source}: fault: must be a list of [[fault]] tables")
    servos = _configured_servos(config)
    return tuple(_entry(i, entry, source, servos) for i, entry in enumerate(entries, start=1))


def dump_faults(faults: Sequence[FaultSpec]) -> str:
    """A fault file listing ``faults`` (``parse_faults`` reads it back to the same entries)."""
    tables = [{k: v for k, v in spec.to_json().items() if k != "index"} for spec in faults]
    return toml.dumps({"fault": tables}) if tables else ""


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


def _entry(index: int, table: Mapping[str, Any], source: str, servos: tuple[int, ...] | None) -> FaultSpec:
    where = f"{source}: fault {index}"
    kind = table.get("kind")
    if kind is None:
        raise UsageError(f"{where}: kind: missing ({_FIELD_HELP['kind']})")
    if not isinstance(kind, str) or kind not in FAULT_KINDS:
        raise UsageError(f"{where}: kind: {show(kind)} is not one of {', '.join(FAULT_KINDS)}")
    where = f"{where} ({kind})"
    spec = FAULT_KINDS[kind]
    allowed = (*_COMMON_KEYS, *spec.keys)
    for key in table:
        if key not in allowed:
            if key == "duration_s":
                raise UsageError(f"{where}: {key}: {kind} happens once; it takes no duration")
            raise UsageError(f"{where}: {key}: unknown key (allowed: {', '.join(allowed)})")
    for key in spec.required:
        if key not in table:
            raise UsageError(f"{where}: {key}: missing ({_FIELD_HELP.get(key, key)})")

    def error(key: str, problem: str) -> UsageError:
        return UsageError(f"{where}: {key}: {problem}")

    shape = _LoopStallTable if kind == "loop_stall" else _FaultTable
    t: _FaultTable = convert(table, shape, error=UsageError, prefix=f"{where}: ")

    if t.at_s is None and t.at_state is None:
        raise error("at_s", "missing: give at_s (simulated seconds from the session start) or at_state")
    if t.at_s is not None and t.at_state is not None:
        raise error("at_state", "give either at_s or at_state, not both")
    if t.at_state is not None and t.at_state not in STATE_PATHS:
        raise error(
            "at_state",
            f"{t.at_state!r} is not a state of the chart (e.g. detect, flip, flip.turn, place.release)",
        )
    if t.at_state is None:
        for key in ("occurrence", "after_s"):
            if key in table:
                raise error(key, "only with at_state (at_s already says when)")
    duration_s = t.duration_s
    if kind == "loop_stall" and duration_s is None:
        duration_s = LOOP_STALL_DEFAULT_S
    if t.servo is not None and servos is not None and t.servo not in servos:
        raise error("servo", f"no servo {t.servo} in the configured chain ({', '.join(map(str, servos))})")
    dx_m, dy_m = t.dx_m, t.dy_m
    if kind == "mug_moved":
        if not (dx_m or dy_m):
            raise error("dx_m", "missing: say how far to move the mug (dx_m, dy_m in metres, not both 0)")
        dx_m, dy_m = dx_m or 0.0, dy_m or 0.0
    return FaultSpec(
        index=index,
        kind=kind,
        at_s=t.at_s,
        at_state=t.at_state,
        occurrence=t.occurrence or 1,
        after_s=t.after_s or 0.0,
        duration_s=duration_s,
        servo=t.servo,
        rate=t.rate,
        seed=0 if kind == "bus_corrupt" and t.seed is None else t.seed,
        value_n=0.0 if kind == "fsr_spike" and t.value_n is None else t.value_n,
        dx_m=dx_m,
        dy_m=dy_m,
        mug=t.mug,
        device=(t.device or "servo") if kind == "bus_unplug" else t.device,
    )


# --- making faults happen ---------------------------------------------------------------------------------

# Which camera fault shows when several act at once: a hung capture hides everything else, a missing frame
# hides what the frame would have been, a bad frame is bad whether or not it is new.
_CAMERA_PRECEDENCE: Final = ("camera_hang", "camera_no_frame", "camera_bad_frame", "camera_stale")
_ONCE_KINDS: Final = frozenset({"fsr_spike", "mug_slip", "mug_moved", "sigterm", "loop_stall"})

Slot = tuple[str, ...]  # one device condition that lasting faults hold: ("servo_silent", "3"), ("camera",)


def slot_of(spec: FaultSpec) -> Slot | None:
    """The device condition a lasting fault holds while it acts; the faults of one slot act together and
    the condition lasts while any of them does. None for a fault that happens once (an overload without
    ``duration_s`` trips once and stays latched in the servo, not in the injector)."""
    kind = spec.kind
    if kind in _ONCE_KINDS or (kind == "servo_overload" and spec.duration_s is None):
        return None
    if kind in SERVO_KINDS:
        return (kind, str(spec.servo))
    if kind in CAMERA_KINDS:
        return ("camera",)
    if kind == "bus_unplug":
        return (kind, spec.device or "servo")
    return (kind,)


@dataclass(frozen=True, slots=True)
class FaultOutcome:
    """What became of one fault of the file: fired (when, ended when) or not, and why not."""

    index: int
    kind: str
    trigger: str
    fired: bool
    fired_at_s: float | None = None
    ended_at_s: float | None = None  # None for a fired fault: it happens once, or lasted to the end
    reason: str | None = None  # why it did not fire (or fired on nothing)
    target: Mapping[str, object] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "index": self.index,
            "kind": self.kind,
            "trigger": self.trigger,
            "fired": self.fired,
        }
        if self.fired_at_s is not None:
            out["fired_at_s"] = self.fired_at_s
        if self.ended_at_s is not None:
            out["ended_at_s"] = self.ended_at_s
        if self.reason is not None:
            out["reason"] = self.reason
        out.update(self.target)
        return out

    def line(self) -> str:
        """``fault 2 (camera_stale at detect #3): not fired: detect was entered 2 times, ...``."""
        head = f"fault {self.index} ({self.kind} {self.trigger})"
        target = f" servo {self.target['servo']}" if self.target.get("servo") is not None else ""
        if not self.fired:
            return f"{head}: NOT FIRED: {self.reason}"
        text = f"{head}: fired{target} at {self.fired_at_s:.3f} s"
        if self.ended_at_s is not None:
            text += f", ended at {self.ended_at_s:.3f} s"
        return text


class FaultInjector:
    """Makes ``faults`` happen in a running daemon (plug ``hooks()`` into ``serve``).

    ``on_fire`` is called with each fault just before it takes effect. ``fired`` lists what happened:
    ``{"kind", "fired_at_s", "index", ...target}`` and ``ended_at_s`` once a lasting fault ends;
    ``outcomes()`` says for every fault of the file whether it fired and, when not, why. Faults are timed on
    the daemon's clock from ``attach`` (the session's start). A fault the cell cannot have is refused at
    ``attach`` with one line naming it (``UsageError``).

    Faults compose: each lasting fault holds its device condition (``slot_of``) while it acts, several on
    one device act together, and each one's end takes away only its own part (the condition goes when the
    last fault holding it ends). Camera faults at once show by ``_CAMERA_PRECEDENCE``; corrupt-packet faults
    at once corrupt as independent sources do, ``1 - (1 - a)(1 - b)``, on the servo they share or else the
    whole chain.
    """

    def __init__(
        self, faults: Sequence[FaultSpec], *, on_fire: Callable[[FaultSpec], None] | None = None
    ) -> None:
        self.faults = tuple(faults)
        self.on_fire = on_fire
        self.fired: list[dict[str, object]] = []
        self._ctx: ServeContext | None = None
        self._cell: FaultCell | None = None
        self._t0 = 0.0
        self._entries: dict[str, int] = {}
        self._waiting = [f for f in self.faults if f.at_state is not None]
        self._due: dict[int, float] = {}  # triggered, waiting for after_s: the time it is due
        self._no_effect: dict[int, str] = {}  # fired on nothing: why
        self._records: dict[int, dict[str, object]] = {}
        self._active: dict[Slot, list[FaultSpec]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._peer: _LoopbackPeer | None = None
        self._ended_s: float | None = None
        self._seen_by_job: dict[str, tuple[float, float]] = {}  # the job's last look: its mug ids, where

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
        from replay.cells import cell_of

        self._ctx = ctx
        self._cell = cell_of(ctx)
        for spec in self.faults:
            self._check(spec)
        self._t0 = ctx.clock.monotonic()
        for spec in self.faults:
            if spec.at_s is not None:
                self._spawn(self._fire_at(spec, self._t0 + spec.at_s))

    def on_publish(self, topic: str, payload: Mapping[str, object]) -> None:
        """Count state entries (``transition`` events on ``events``) for the ``at_state`` faults: an entry
        from outside the state; a resume after a pause goes back into a state and is not one."""
        if topic == "detections":
            with contextlib.suppress(BadMessage):  # (not detections: nothing seen)
                self._seen_by_job = _job_mugs(as_message(payload, Detections, name=topic))
            return
        if topic != "events" or self._ctx is None:
            return
        try:
            event = as_message(payload, Event, name=topic)
        except BadMessage:
            return
        if event.kind != "transition" or event.trigger == "resume":
            return
        dest = event.dest if isinstance(event.dest, str) else ""
        source = event.source if isinstance(event.source, str) else ""
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
                    due = self._ctx.clock.monotonic() + spec.after_s
                    self._due[spec.index] = due - self._t0
                    self._spawn(self._fire_at(spec, due))

    def close(self) -> None:
        """End every fault still on (a replugged bus, a freed disk) and close the loopback peer."""
        if self._ctx is not None and self._ended_s is None:
            self._ended_s = round(self._ctx.clock.monotonic() - self._t0, 3)
        for task in self._tasks:
            task.cancel()
        for slot, active in self._active.items():
            if active and slot != ("zenoh_peer_loss",):
                before = tuple(active)
                active.clear()
                with contextlib.suppress(Exception):
                    self._apply(slot, before, ())
        self._active.clear()
        if self._peer is not None:
            with contextlib.suppress(Exception):
                self._peer.close()
            self._peer = None

    # --- what became of each fault -------------------------------------------------------------------------

    @property
    def acts_on_recording(self) -> bool:
        """Whether a fault of the plan acts on the recording (a full disk): the replay must write it."""
        return any(f.kind in RECORDING_KINDS for f in self.faults)

    def outcomes(self) -> tuple[FaultOutcome, ...]:
        """Every fault of the file, fired or not, and why not (past the end of the run, the state never
        entered, the occurrence not reached, nothing to act on)."""
        end = self._ended_s
        if end is None and self._ctx is not None:
            end = round(self._ctx.clock.monotonic() - self._t0, 3)
        return tuple(self._outcome(spec, end) for spec in self.faults)

    def unfired(self) -> tuple[FaultOutcome, ...]:
        return tuple(o for o in self.outcomes() if not o.fired)

    def _outcome(self, spec: FaultSpec, end: float | None) -> FaultOutcome:
        record = self._records.get(spec.index)
        ran = "the run" if end is None else f"the run ended at {end:.3f} s"
        if record is not None:
            # (``record`` is the rig's own fault_injected event as it builds it: its target keys are the
            # fault kind's own, so it stays a table.)
            target = {k: v for k, v in record.items() if k not in _RECORD_KEYS}
            fired_at = record.get("fired_at_s")
            ended_at = record.get("ended_at_s")
            reason = self._no_effect.get(spec.index)
            return FaultOutcome(
                spec.index,
                spec.kind,
                spec.trigger,
                reason is None,
                float(fired_at) if isinstance(fired_at, int | float) else None,
                float(ended_at) if isinstance(ended_at, int | float) else None,
                None if reason is None else f"it came at {fired_at} s with nothing to act on: {reason}",
                target,
            )
        if spec.at_s is not None:
            reason = f"past the end of the run: due at {spec.at_s:g} s, {ran}"
        else:
            assert spec.at_state is not None
            entries = self._entries.get(spec.at_state, 0)
            due = self._due.get(spec.index)
            if due is not None:
                reason = f"past the end of the run: due at {due:.3f} s ({spec.trigger}), {ran}"
            elif entries == 0:
                reason = f"the job never entered {spec.at_state}"
            else:
                times = "once" if entries == 1 else f"{entries} times"
                reason = f"occurrence {spec.occurrence} not reached: the job entered {spec.at_state} {times}"
        return FaultOutcome(spec.index, spec.kind, spec.trigger, False, reason=reason)

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
        self._due.pop(spec.index, None)
        if self.on_fire is not None:
            self.on_fire(spec)
        fired_at = round(ctx.clock.monotonic() - self._t0, 3)
        record: dict[str, object] = {"kind": spec.kind, "fired_at_s": fired_at, "index": spec.index}
        slot = slot_of(spec)
        record.update(self._once(spec) if slot is None else self._start(slot, spec))
        self.fired.append(record)
        self._records[spec.index] = record
        self._report(record)
        if slot is not None and spec.duration_s is not None:
            self._spawn(self._end_after(spec, slot, record))

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

    def _start(self, slot: Slot, spec: FaultSpec) -> dict[str, object]:
        active = self._active.setdefault(slot, [])
        before = tuple(active)
        active.append(spec)
        self._apply(slot, before, tuple(active))
        return _target(spec, self._peer)

    async def _end_after(self, spec: FaultSpec, slot: Slot, record: dict[str, object]) -> None:
        ctx = self._ctx
        assert ctx is not None
        assert spec.duration_s is not None
        if spec.kind == "zenoh_peer_loss":  # Zenoh notices a lost link on the wall clock
            await _wall_wait(spec.duration_s)
        else:
            await ctx.clock.sleep(spec.duration_s)
        active = self._active.get(slot, [])
        before = tuple(active)
        active.remove(spec)
        if slot == ("zenoh_peer_loss",):
            if not active and self._peer is not None:
                await asyncio.to_thread(self._peer.open)
        else:
            self._apply(slot, before, tuple(active))
        record["ended_at_s"] = round(ctx.clock.monotonic() - self._t0, 3)
        still = [s.index for s in active]
        log.info("fault_ended", fault=spec.kind, index=spec.index, ended_at_s=record["ended_at_s"])
        event: dict[str, object] = {
            "kind": "fault_ended",
            "fault": spec.kind,
            "index": spec.index,
            "ended_at_s": record["ended_at_s"],
            "state": ctx.job.chart.state,
            "t": ctx.clock.now(),
        }
        if still:
            event["still_acting"] = still  # the device stays as the other faults on it hold it
        ctx.session.publish("events", event)

    def _apply(self, slot: Slot, before: tuple[FaultSpec, ...], after: tuple[FaultSpec, ...]) -> None:
        """Set the device condition ``slot`` to what the faults ``after`` hold together (was: ``before``)."""
        from replay.cells import set_camera_fault

        kind = slot[0]
        ctx = self._ctx
        assert ctx is not None
        if kind == "camera":
            first = min(after, key=lambda s: _CAMERA_PRECEDENCE.index(s.kind), default=None)
            assert self._cell is not None
            set_camera_fault(self._cell.camera(), None if first is None else CAMERA_KINDS[first.kind])
            return
        if kind == "bus_corrupt":
            assert self._cell is not None
            rate, seed, servo = _combined_corruption(after)
            self._cell.bus_corrupt(rate, seed=seed, servo=servo)
            return
        if bool(before) == bool(after):
            return
        on = bool(after)
        if kind == "disk_full":
            disk, clock = ctx.recording.disk, ctx.clock
            (disk.fill if on else disk.free)(_log_time_ns(clock.now()))
            return
        if kind == "zenoh_peer_loss":
            peer = self._peer
            assert peer is not None
            # Closing or opening a Zenoh session blocks until its links are up or down: off the loop.
            self._spawn(asyncio.to_thread(peer.close if on else peer.open))
            return
        cell = self._cell
        assert cell is not None
        if kind == "bus_unplug":
            cell.unplugged(slot[1], on=on)
        elif kind == "fsr_drop":
            cell.fsr_dropped(on=on)
        elif kind == "fsr_silent":
            cell.fsr_silent(on=on)
        else:
            servo = int(slot[1])
            {
                "servo_overload": cell.servo_overloaded,
                "servo_overheat": cell.servo_hot,
                "servo_voltage": cell.servo_low_voltage,
                "servo_silent": cell.servo_silent,
            }[kind](servo, on=on)

    def _once(self, spec: FaultSpec) -> dict[str, object]:
        """Make a fault that happens once happen; what it acted on."""
        kind = spec.kind
        if kind == "sigterm":
            os.kill(os.getpid(), signal.SIGTERM)
            return {}
        if kind == "loop_stall":
            assert spec.duration_s is not None
            _stall(spec.duration_s)
            return {"stalled_s": spec.duration_s}
        cell = self._cell
        assert cell is not None
        if kind == "servo_overload":
            assert spec.servo is not None
            cell.servo_trip(spec.servo)
            return {"servo": spec.servo}
        if kind == "fsr_spike":
            cell.fsr_spike(spec.value_n or 0.0)
            return {"value_n": spec.value_n}
        if kind == "mug_slip":
            carried = self._ctx.job.status().current_mug if self._ctx is not None else None
            world_mug = cell.slip()
            if world_mug is None:
                self._no_effect[spec.index] = "no mug was held"
            return {"mug": carried if world_mug is not None else None, "world_mug": world_mug}
        return self._move_mug(spec, cell)

    def _move_mug(self, spec: FaultSpec, cell: FaultCell) -> dict[str, object]:
        """Move a counter mug of the world: ``mug`` names it by the job's id (where the job last saw it;
        a name the job does not know is taken as the world's own, as fault files before job ids did), by
        default the one farthest from the gripper. The event names both."""
        ctx = self._ctx
        assert ctx is not None
        dx, dy = spec.dx_m or 0.0, spec.dy_m or 0.0
        standing = {m: (x, y) for m, x, y in cell.counter_mugs()}
        if spec.mug is not None and spec.mug in self._seen_by_job:
            world_mug = _nearest(self._seen_by_job[spec.mug], standing)
            if world_mug is None:
                self._no_effect[spec.index] = f"the job's mug {spec.mug} was not standing on the counter"
                return {"mug": spec.mug, "world_mug": None}
        else:
            world_mug = spec.mug or next(iter(standing), None)
        if world_mug is None:
            self._no_effect[spec.index] = "no mug stood on the counter"
            return {"mug": None, "world_mug": None}
        job_mug = self._job_id_of(standing.get(world_mug))
        named: dict[str, object] = {"mug": job_mug, "world_mug": world_mug}
        if world_mug not in standing:
            self._no_effect[spec.index] = f"mug {world_mug} was not standing on the counter"
            return named
        x0, y0, x1, y1 = ctx.config.cell.counter_region_m
        x, y = standing[world_mug][0] + dx, standing[world_mug][1] + dy
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            self._no_effect[spec.index] = (
                f"moving mug {world_mug} by ({dx:g}, {dy:g}) m would put it at ({x:.3f}, {y:.3f}) m, off "
                f"the counter region [{x0:g}, {y0:g}, {x1:g}, {y1:g}]"
            )
            return named
        try:
            cell.move_mug(world_mug, dx, dy)
        except ValueError as e:
            self._no_effect[spec.index] = str(e)
            return named
        return {**named, "dx_m": spec.dx_m, "dy_m": spec.dy_m}

    def _job_id_of(self, where: tuple[float, float] | None) -> str | None:
        """The job's id of the mug standing at ``where`` (None: the job has not seen it there)."""
        return None if where is None else _nearest(where, self._seen_by_job)


# How far the job's last sight of a mug may be from where the world has it, to be the same mug (m).
_SAME_MUG_M: Final = 0.05


def _nearest(where: tuple[float, float], candidates: Mapping[str, tuple[float, float]]) -> str | None:
    """The key of the candidate nearest ``where``, within ``_SAME_MUG_M``; None when none is."""
    best = min(candidates, key=lambda k: math.dist(where, candidates[k]), default=None)
    if best is None or math.dist(where, candidates[best]) > _SAME_MUG_M:
        return None
    return best


def _job_mugs(detections: Detections) -> dict[str, tuple[float, float]]:
    """The mugs a ``detections`` message names, by the job's id: where they were seen."""
    return {m.id: (float(m.x_m), float(m.y_m)) for m in detections.mugs if isinstance(m.id, str)}


_RECORD_KEYS: Final = ("kind", "index", "fired_at_s", "ended_at_s")
_CELL_KINDS: Final = frozenset(FAULT_KINDS) - {"sigterm", "loop_stall", "disk_full", "zenoh_peer_loss"}


def _target(spec: FaultSpec, peer: _LoopbackPeer | None) -> dict[str, object]:
    """What a lasting fault acts on, for its ``fault_injected`` event."""
    if spec.kind in SERVO_KINDS:
        return {"servo": spec.servo}
    if spec.kind == "bus_corrupt":
        target: dict[str, object] = {"rate": spec.rate}
        if spec.servo is not None:
            target["servo"] = spec.servo
        return target
    if spec.kind == "bus_unplug":
        return {"device": spec.device or "servo"}
    if spec.kind == "zenoh_peer_loss" and peer is not None:
        return {"peer": peer.endpoint}
    return {}


def _combined_corruption(active: Sequence[FaultSpec]) -> tuple[float, int, int | None]:
    """The rate, seed and servo of corrupt-packet faults acting together (rate 0: none)."""
    if not active:
        return 0.0, 0, None
    clean = 1.0
    for spec in active:
        clean *= 1.0 - (spec.rate or 0.0)
    servos = {spec.servo for spec in active}
    return 1.0 - clean, active[0].seed or 0, servos.pop() if len(servos) == 1 else None


def _log_time_ns(t: float) -> int:
    """A recording's log time for the clock's ``now()`` (as ``serve`` stamps every message)."""
    return round(t * 1e9)


async def _wall_wait(seconds: float) -> None:
    """Wait ``seconds`` of wall time, whatever clock the session is on, without holding it up: Zenoh
    notices a lost link on the wall clock, so a peer lost for a few simulated seconds at full speed would be
    back before anyone noticed it had gone. Simulated time runs on meanwhile (the daemon's own timers, such as
    the one that settles a change of links, fire as usual)."""
    loop = asyncio.get_running_loop()
    woken: asyncio.Future[None] = loop.create_future()

    def wake() -> None:
        if not woken.done():
            woken.set_result(None)

    timer = threading.Timer(seconds, loop.call_soon_threadsafe, (wake,))
    timer.daemon = True
    timer.start()
    try:
        await woken
    finally:
        timer.cancel()


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


__all__ = [
    "CAMERA_KINDS",
    "FAULT_KINDS",
    "SERVO_KINDS",
    "FaultInjector",
    "FaultOutcome",
    "FaultSpec",
    "KindSpec",
    "dump_faults",
    "load_fault_file",
    "parse_faults",
    "slot_of",
]
