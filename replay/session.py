"""A recorded job, read back for a replay: what it ran on, the inputs the daemon consumed, and its trace.

``RecordedSession.load`` reads one job file (``<robot>-<start>-job.mcap``) and checks that it is one: an
MCAP file that is not a recording, a recording of another program, an idle file or a header without what a
replay needs is a ``ReplayError`` with one line naming the file and what is wrong. A file cut by a crash is
read up to the cut (``cut``).

Times. Every recorded message carries its log time, the session clock's ``now()``: on a simulated clock the
session's wall-clock start plus simulated time, on the robot the wall clock. Inputs also carry the
driver's monotonic time of the call (``t_read``, ``t_start``, ``t_end``). A trace's times (``Trace``) are
seconds from the job's ``start`` transition, so a recorded trace and its replay can be laid side by side
whatever clock either ran on.
"""

from __future__ import annotations

import array
import bisect
import dataclasses
import functools
import itertools
import json
import math
import operator
import statistics
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from daemon.config import Config, load_config
from daemon.errors import ConfigError
from recorder import HEADER_TOPIC, read_messages
from recorder.errors import RecordingError
from recorder.reader import RecordedMessage, RecordingRead, decoded_as, json_object
from replay.errors import ReplayError
from wire.messages import (
    TOPICS,
    UNSET,
    BadMessage,
    CloseAsked,
    Command,
    Event,
    EventKind,
    FollowAsked,
    Force,
    Gripper,
    HeaderClock,
    HeaderJob,
    Holding,
    InputJoints,
    InputPosition,
    Message,
    OpenAsked,
    ReadFailed,
    Started,
    State,
    UnsetType,
    convert,
    header_part,
    reply_of,
    view,
)
from wire.schemas import topic_suffix as _topic_suffix

# What follows ``dishbot/<robot_id>/`` in a topic, worked out once per topic (a recording has a few dozen,
# and each of its messages is looked at by topic).
topic_suffix: Final = functools.lru_cache(maxsize=4096)(_topic_suffix)

# The backends a replay can rebuild, by the name the session header's scene gives.
SIM_BACKENDS: Final = {"sim-kinematic": "kinematic", "sim-mujoco": "mujoco"}
# Every backend whose recordings replay (a hardware one in a simulated stand-in cell, ``replay.resim``).
RECORDED_BACKENDS: Final = {**SIM_BACKENDS, "hardware": "hardware"}
# Events that say something about this run of the program rather than about the job, left out of a trace
# comparison: links to other machines, the recording itself, faults a replay injected.
UNCOMPARED_EVENTS: Final = frozenset(
    {"connection_lost", "connection_restored", "fault_injected", "recording_failed", "zenoh_insecure"}
)
# Commands that change nothing are not recorded (``status``); these are sent again by a replay.
REPLAYED_VERBS: Final = ("start", "pause", "resume", "stop", "estop", "reset")


@dataclass(frozen=True, slots=True)
class TraceEvent:
    kind: str
    t_s: float  # from the job's start
    state: str
    detail: Mapping[str, object] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        return {**self.detail, "kind": self.kind, "t_s": round(self.t_s, 6), "state": self.state}


@dataclass(frozen=True, slots=True)
class Trace:
    """What a job did, as its recording tells: every state entered (in order, with its time from the
    job's start), every event, and the state it ended in."""

    states: tuple[str, ...]
    state_times_s: tuple[float, ...]
    events: tuple[TraceEvent, ...]
    final_state: str
    duration_s: float  # from the start transition to the last transition
    outputs: tuple[DeviceCommand, ...]  # the device commands the daemon gave, in order

    def compared_events(self) -> list[TraceEvent]:
        return [e for e in self.events if e.kind not in UNCOMPARED_EVENTS]

    def events_by_kind(self) -> dict[str, list[TraceEvent]]:
        out: dict[str, list[TraceEvent]] = {}
        for e in self.events:
            out.setdefault(e.kind, []).append(e)
        return out

    def state_at(self, t_s: float) -> str:
        """The state the job was in at ``t_s`` (idle before it started)."""
        state = "idle"
        for name, t in zip(self.states, self.state_times_s, strict=True):
            if t > t_s:
                break
            state = name
        return state

    def cut(self, t_s: float) -> Trace:
        """The trace up to ``t_s``: what a recording cut there holds."""
        n = sum(1 for t in self.state_times_s if t <= t_s)
        return Trace(
            self.states[:n],
            self.state_times_s[:n],
            tuple(e for e in self.events if e.t_s <= t_s),
            self.states[n - 1] if n else "idle",
            self.state_times_s[n - 1] if n else 0.0,
            tuple(c for c in self.outputs if c.t_s <= t_s),
        )


@dataclass(frozen=True, slots=True)
class Divergence:
    """Where a replay first did something else than the recording: at ``t_s`` from the job's start, in
    ``state``, ``what`` differed (``state``, ``event``, ``follow``, ``gripper``, ``grasp``, ``plan``,
    ``observation``, ``command``, ``fault``, ``recording_end``)."""

    t_s: float
    state: str
    what: str
    expected: str
    got: str

    def to_json(self) -> dict[str, object]:
        return {
            "t_s": round(self.t_s, 6),
            "state": self.state,
            "what": self.what,
            "expected": self.expected,
            "got": self.got,
        }

    def line(self) -> str:
        return (
            f"diverged at {self.t_s:.3f} s in {self.state} ({self.what}): expected {self.expected}, "
            f"got {self.got}"
        )


@dataclass(frozen=True, slots=True)
class DeviceCommand:
    """One command the daemon gave a device, as compared between a recording and its replay: what was asked
    (a move's label and goal, an opening, a close's force threshold), not how long it took or how it ended."""

    what: str  # follow, open, close
    label: str
    values: tuple[float, ...]
    t_s: float  # from the job's start

    def same(self, other: DeviceCommand, *, tolerance: float = 1e-4) -> bool:
        return (
            self.what == other.what
            and self.label == other.label
            and len(self.values) == len(other.values)
            and all(abs(a - b) <= tolerance for a, b in zip(self.values, other.values, strict=True))
        )

    def describe(self) -> str:
        values = ", ".join(f"{v:.4f}" for v in self.values)
        if self.what == "follow":
            return f"follow {self.label} to [{values}]"
        if self.what == "open":
            return f"open the gripper to {values} m" if self.values else "open the gripper fully"
        return f"close the gripper until {values} N"


def device_command(suffix: str, payload: Mapping[str, object] | Message, t_s: float) -> DeviceCommand | None:
    """The device command a recorded ``output/*`` (or grasp) message stands for, or one the daemon asks now
    (its request as the same topic's fields: ``FollowAsked``, ``OpenAsked``, ``CloseAsked`` or a mapping of
    them); None for the other topics, and for a payload without what its topic asks (not a command)."""
    try:
        if suffix == "output/follow":
            follow = view(payload, FollowAsked, name=suffix)
            return DeviceCommand("follow", follow.label, tuple(float(v) for v in follow.end_rad), t_s)
        if suffix == "output/gripper":
            gripper = view(payload, OpenAsked, name=suffix)
            if gripper.action != "open":
                return None
            aperture = () if gripper.aperture_m is None else (float(gripper.aperture_m),)
            return DeviceCommand("open", "", aperture, t_s)
        if suffix in ("input/grasp", "input/grasp_failed"):
            close = view(payload, CloseAsked, name=suffix)
            threshold = () if close.force_threshold_n is None else (float(close.force_threshold_n),)
            return DeviceCommand("close", "", threshold, t_s)
    except BadMessage:
        return None
    return None


# The topics ``device_command`` reads.
_COMMAND_SUFFIXES: Final = frozenset({"output/follow", "output/gripper", "input/grasp", "input/grasp_failed"})
# The topic suffixes a replay reads from a recording besides the driver-boundary ones (``input/*``,
# ``output/*``): the trace's (events, state), the served placement plan (plan), and what the re-simulated
# world is rebuilt from (``replay.resim``: gripper, detections, also state and events).
_REPLAYED_SUFFIXES: Final = frozenset({"events", "state", "plan", "gripper", "detections"})


@functools.lru_cache(maxsize=4096)
def replayed_topic(topic: str) -> bool:
    """Whether a replay reads ``topic`` of a recording (``RecordedSession.load`` decodes no other: not the
    telemetry, the log, nor Foxglove's views such as ``/tf``)."""
    if topic == HEADER_TOPIC:
        return True
    suffix = topic_suffix(topic)
    return suffix in _REPLAYED_SUFFIXES or suffix.startswith(("input/", "output/"))


@functools.lru_cache(maxsize=4096)
def traced_topic(topic: str) -> bool:
    """Whether ``trace_of_messages`` reads ``topic`` (a replay's tee keeps no other)."""
    suffix = topic_suffix(topic)
    return suffix in ("events", "state") or suffix in _COMMAND_SUFFIXES


def trace_of(read: RecordingRead, *, start_ns: int | None = None) -> Trace:
    """The trace in a recording, its times from ``start_ns`` (default: the job's ``start`` transition)."""
    return trace_of_messages(read.messages, start_ns=start_ns, first_ns=read.start_ns)


def trace_of_messages(
    messages: Sequence[RecordedMessage], *, start_ns: int | None = None, first_ns: int | None = None
) -> Trace:
    """The trace in ``messages`` (as recorded, or as the daemon published and recorded them), its times
    from ``start_ns`` (default: the job's ``start`` transition, else ``first_ns``)."""
    if start_ns is None:
        start_ns = job_start_ns(messages)
    if start_ns is None:
        start_ns = first_ns or 0
    states: list[str] = []
    times: list[float] = []
    events: list[TraceEvent] = []
    outputs: list[DeviceCommand] = []
    final = ""
    started = False
    for m in messages:
        suffix = topic_suffix(m.topic)
        t_s = (m.log_time_ns - start_ns) / 1e9
        if not started:  # the trace begins with the start transition (what came before it, such as the
            # scene being set up, may be in the file before or not, as the file was opened)
            started = suffix == "events" and _is_start(m.decoded(Event))
            if not started:
                continue
        if suffix == "events":
            payload = m.payload  # (decoded once: a compact read decodes at each ``payload``)
            try:
                event = convert(payload, Event, name=suffix)
            except BadMessage:  # not an event: nothing of it in the trace
                continue
            detail = {k: v for k, v in payload.items() if k not in ("kind", "t", "state", "t_device")}
            events.append(TraceEvent(event.kind, t_s, _text(event.state), detail))
            if event.kind == "transition":
                dest = _text(event.dest)
                states.append(dest)
                times.append(t_s)
                final = dest
        elif suffix == "state" and not final:
            state = m.decoded(State)
            final = state.state if state is not None else ""
        elif suffix in _COMMAND_SUFFIXES:
            command = device_command(suffix, m.payload, t_s)
            if command is not None:
                outputs.append(command)
    return Trace(
        tuple(states),
        tuple(times),
        tuple(events),
        final or "idle",
        times[-1] if times else 0.0,
        tuple(outputs),
    )


def job_start(messages: Sequence[RecordedMessage]) -> RecordedMessage | None:
    """The job's ``start`` transition."""
    for m in messages:
        if topic_suffix(m.topic) == "events" and _is_start(m.decoded(Event)):
            return m
    return None


def _is_start(event: Event | None) -> bool:
    """Whether an event is the job's ``start`` transition."""
    return event is not None and event.kind == "transition" and event.trigger == "start"


def _text(value: str | UnsetType) -> str:
    return "" if isinstance(value, UnsetType) else value


def job_start_ns(messages: Sequence[RecordedMessage]) -> int | None:
    """The log time of the job's ``start`` transition."""
    start = job_start(messages)
    return None if start is None else start.log_time_ns


def compare(expected: Trace, got: Trace, *, prefix: bool = False) -> Divergence | None:
    """The first place where ``got`` did otherwise than ``expected``: the states entered, the events (their
    kinds, in order, those of ``UNCOMPARED_EVENTS`` left out) and the device commands; None when they agree.
    Times are not compared (they are reported). With ``prefix`` (``expected`` is a recording cut short),
    ``got`` may go on where ``expected`` ends."""
    if prefix:
        n, m, k = len(expected.states), len(expected.outputs), len(expected.compared_events())
        got = dataclasses.replace(
            got,
            states=got.states[:n],
            state_times_s=got.state_times_s[:n],
            events=tuple(got.compared_events()[:k]),
            outputs=got.outputs[:m],
        )
    found: list[Divergence] = []
    for i, (a, b) in enumerate(zip(expected.states, got.states, strict=False)):
        if a != b:
            t = got.state_times_s[i]
            found.append(Divergence(t, got.state_at(t - 1e-9), "state", f"enter {a}", f"enter {b}"))
            break
    else:
        if len(expected.states) != len(got.states):
            n = min(len(expected.states), len(got.states))
            if len(expected.states) > n:
                t = expected.state_times_s[n]
                entered = f"enter {expected.states[n]}"
                found.append(Divergence(t, got.final_state, "state", entered, f"stay in {got.final_state}"))
            else:
                t = got.state_times_s[n]
                stayed = f"stay in {expected.final_state}"
                found.append(Divergence(t, got.state_at(t - 1e-9), "state", stayed, f"enter {got.states[n]}"))
    ea, eb = expected.compared_events(), got.compared_events()
    for a_event, b_event in zip(ea, eb, strict=False):
        if a_event.kind != b_event.kind:
            found.append(
                Divergence(
                    b_event.t_s, b_event.state, "event", f"event {a_event.kind}", f"event {b_event.kind}"
                )
            )
            break
    else:
        if len(ea) != len(eb):
            longer = ea if len(ea) > len(eb) else eb
            nxt = longer[min(len(ea), len(eb))]
            exp = f"event {nxt.kind}" if longer is ea else "no more events"
            gt = f"event {nxt.kind}" if longer is eb else "no more events"
            found.append(Divergence(nxt.t_s, nxt.state, "event", exp, gt))
    for a_cmd, b_cmd in zip(expected.outputs, got.outputs, strict=False):
        if not a_cmd.same(b_cmd):
            found.append(
                Divergence(b_cmd.t_s, got.state_at(b_cmd.t_s), "device", a_cmd.describe(), b_cmd.describe())
            )
            break
    else:
        n = min(len(expected.outputs), len(got.outputs))
        if len(expected.outputs) > n:
            c = expected.outputs[n]
            found.append(
                Divergence(c.t_s, got.state_at(c.t_s), "device", c.describe(), f"no more ({got.final_state})")
            )
        elif len(got.outputs) > n:
            c = got.outputs[n]
            found.append(
                Divergence(
                    c.t_s, got.state_at(c.t_s), "device", f"no more ({expected.final_state})", c.describe()
                )
            )
    return min(found, key=lambda d: d.t_s) if found else None


class Recorded:
    """One recorded input or output: its topic suffix, its log time (ns) and its payload.

    Loaded from a recording (``RecordedSession.load``) it keeps only the payload's JSON bytes as recorded,
    shared with the session's ``read``, and decodes them at each ``payload`` and ``message``: a long
    session's streams take about their size in the file (checked when loaded, so a decode cannot fail)."""

    __slots__ = ("_data", "_typed", "kind", "t_ns")

    kind: str
    t_ns: int
    _data: Mapping[str, object] | bytes  # the payload, or its JSON bytes
    _typed: Message | type[Message] | None  # the message, or its declared type to decode it as

    def __init__(
        self,
        kind: str,
        t_ns: int,
        payload: Mapping[str, object] | None = None,
        message: Message | None = None,
        *,
        raw: bytes | None = None,
        declared: type[Message] | None = None,
    ) -> None:
        data = payload if payload is not None else raw
        if data is None or (payload is not None and raw is not None):
            raise TypeError("a Recorded holds either its payload or its raw JSON bytes")
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "t_ns", t_ns)
        object.__setattr__(self, "_data", data)
        object.__setattr__(self, "_typed", message if message is not None else declared)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"Recorded is immutable (cannot set {name})")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"Recorded is immutable (cannot delete {name})")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Recorded):
            return NotImplemented
        return (self.kind, self.t_ns, self.payload, self.message) == (
            other.kind,
            other.t_ns,
            other.payload,
            other.message,
        )

    __hash__ = None  # type: ignore[assignment]  # (a payload is a dict)

    def __repr__(self) -> str:
        return f"Recorded(kind={self.kind!r}, t_ns={self.t_ns!r}, payload={self.payload!r})"

    @property
    def payload(self) -> Mapping[str, object]:
        data = self._data
        if isinstance(data, bytes):
            return json_object(data)
        return data

    @property
    def message(self) -> Message | None:
        """The payload as its declared message (``wire.messages``), for the driver-boundary topics a replay
        serves; None for the open ones (device events) and the plan (``PlanResult.from_json`` reads it).
        Held as bytes, decoded straight into it (no dict between) at each call: a caller that reads it
        more than once keeps what it got."""
        typed = self._typed
        if isinstance(typed, type):
            data = self._data
            if isinstance(data, bytes):
                return decoded_as(data, typed, name=self.kind)
            return convert(data, typed, name=self.kind)
        return typed


@dataclass(frozen=True, slots=True)
class Anchor:
    """Where in the job an input from outside it came (an operator's command, a device's event): after
    ``transitions`` transitions since the job's start (the start's own included) and ``device_commands``
    device commands, ``after_s`` seconds after the later of those two (recorded monotonic time)."""

    transitions: int
    device_commands: int
    after_s: float

    def describe(self) -> str:
        return (
            f"{self.after_s:.3f} s after transition {self.transitions} and device command "
            f"{self.device_commands}"
        )


# Inputs served by the time of their read (a read that failed then fails now), by stream: the recorded
# topics that make each.
TIMED_INPUTS: Final[Mapping[str, tuple[str, ...]]] = {
    "input/joints": ("input/joints", "input/joints_failed"),
    "input/force": ("input/force",),
    "input/holding": ("input/holding",),
}


@dataclass(frozen=True, slots=True)
class TimedInputs:
    """One stream of ``TIMED_INPUTS`` as a replay serves it, taken from the messages as ``load`` decoded
    them (once): the records in the order of their reads (the recorded monotonic time of each, an older
    recording's log time), whether each read worked, who read each joint sample (``daemon.recorded.
    joint_reader``; None when the recording does not say) and each holding flag."""

    records: tuple[Recorded, ...] = ()
    read_times: tuple[float, ...] = ()
    ok: tuple[bool, ...] = ()
    readers: tuple[str | None, ...] = ()
    holding: tuple[bool, ...] = ()  # (input/holding only)


class _TimedFacts:
    """What ``TimedInputs`` takes of each timed input, as ``load`` decodes it (the message is not kept: a
    long session's inputs are held as their bytes)."""

    def __init__(self) -> None:
        self.records: list[Recorded] = []
        self.t_read: list[float | None] = []  # None: not recorded (an older recording)
        self.ok: list[bool] = []
        self.readers: list[str | None] = []
        self.holding: list[bool] = []

    def add(self, r: Recorded, m: Message) -> None:
        t = m.t_read if isinstance(m, InputJoints | Force | Holding | ReadFailed) else UNSET
        reader = m.reader if isinstance(m, InputJoints | ReadFailed) else UNSET
        self.records.append(r)
        self.t_read.append(None if isinstance(t, UnsetType) else float(t))
        self.ok.append(not isinstance(m, ReadFailed))
        self.readers.append(None if isinstance(reader, UnsetType) else sys.intern(reader))
        if isinstance(m, Holding):
            self.holding.append(m.holding)


@dataclass(frozen=True, slots=True)
class GripperTelemetry:
    """The gripper as the recorded telemetry read it (``gripper``), by the recorded monotonic time of each
    read (its ``t_device``; a message without one: its log time): a replay hands these to the telemetry
    while it follows the recording instead of reading the stand-in's gripper over its bus, which cost a
    tenth of a kinematic replay (the job itself never reads the gripper: only the telemetry does). Held as
    arrays of numbers, as an hour of 50 Hz telemetry is 180 000 reads."""

    read_times: array.array[float] = field(default_factory=lambda: array.array("d"))
    aperture_m: array.array[float] = field(default_factory=lambda: array.array("d"))
    load: array.array[float] = field(default_factory=lambda: array.array("d"))  # 0 when not recorded


class _GripperFacts:
    """What ``GripperTelemetry`` takes of each ``gripper`` message, as ``load`` reads them (a malformed one
    is left out, as ``replay.resim.world_at`` leaves it out)."""

    def __init__(self) -> None:
        self.t_device = array.array("d")  # NaN: not recorded
        self.logged_s = array.array("d")
        self.aperture_m = array.array("d")
        self.load = array.array("d")

    def add(self, m: RecordedMessage) -> None:
        g = m.decoded(Gripper)
        if g is None:
            return
        self.t_device.append(math.nan if isinstance(g.t_device, UnsetType) else float(g.t_device))
        self.logged_s.append(m.log_time_ns / 1e9)
        self.aperture_m.append(float(g.aperture_m))
        self.load.append(0.0 if isinstance(g.load, UnsetType) else float(g.load))

    def telemetry(self, mono_offset_s: float) -> GripperTelemetry:
        """The reads by their recorded monotonic time (in the order they were read)."""
        times = array.array(
            "d",
            (
                logged - mono_offset_s if math.isnan(t) else t
                for t, logged in zip(self.t_device, self.logged_s, strict=True)
            ),
        )
        aperture, load = self.aperture_m, self.load
        if not all(map(operator.le, times, itertools.islice(times, 1, None))):
            order = sorted(range(len(times)), key=times.__getitem__)
            times = array.array("d", (times[i] for i in order))
            aperture = array.array("d", (aperture[i] for i in order))
            load = array.array("d", (load[i] for i in order))
        return GripperTelemetry(times, aperture, load)


def _no_facts() -> dict[str, _TimedFacts]:
    """An empty ``_TimedFacts`` for each topic of ``TIMED_INPUTS``."""
    return {topic: _TimedFacts() for topics in TIMED_INPUTS.values() for topic in topics}


def _timed_of(facts: Mapping[str, _TimedFacts], mono_offset_s: float) -> dict[str, TimedInputs]:
    """Every stream of ``TIMED_INPUTS`` from its topics' facts (a stream's topics one after the other, as
    the replay consumed them: a stable sort)."""
    return {
        name: _timed_inputs([facts[t] for t in topics], mono_offset_s)
        for name, topics in TIMED_INPUTS.items()
    }


def _timed_inputs(facts: Sequence[_TimedFacts], mono_offset_s: float) -> TimedInputs:
    """One stream's ``TimedInputs`` from its topics' facts (in the order of ``TIMED_INPUTS``: a stable
    sort keeps the order the replay consumed them in)."""
    records = [r for f in facts for r in f.records]
    times = [
        r.t_ns / 1e9 - mono_offset_s if t is None else t
        for f in facts
        for r, t in zip(f.records, f.t_read, strict=True)
    ]
    ok = [k for f in facts for k in f.ok]
    readers = [reader for f in facts for reader in f.readers]
    holding = [h for f in facts for h in f.holding]
    if len(holding) != len(records):
        holding = []
    if not all(map(operator.le, times, itertools.islice(times, 1, None))):
        # (Out of order: sorted, stably, the order consumed. A simulated session's reads mostly come in
        # order already, and a long session's index is not built twice.)
        order = sorted(range(len(records)), key=times.__getitem__)
        records, times = [records[i] for i in order], [times[i] for i in order]
        ok, readers = [ok[i] for i in order], [readers[i] for i in order]
        holding = [holding[i] for i in order] if holding else []
    return TimedInputs(tuple(records), tuple(times), tuple(ok), tuple(readers), tuple(holding))


# The topics of the device commands a job gives (those ``daemon.backend.JobPosition`` counts), by their
# start.
_DEVICE_COMMAND_TOPICS: Final = (
    "output/follow",
    "output/gripper",
    "output/arm",
    "input/grasp",
    "input/grasp_failed",
    "input/observation",
    "input/observe_failed",
)
# Recorded inputs kept as their payloads only: device events are open (a driver's own keys), a plan is read
# by ``PlanResult.from_json``.
_UNTYPED: Final = frozenset({"input/device_event", "plan"})
# What a recording made before a setting existed did, for the settings whose default is not that: before
# ``[planner] footprint`` (or while ``rect`` was its default) the placement planned with rectangles; before
# ``[arm] set_down_slow_m`` the arm set its mugs down at fine speed all the way.
_BEFORE_SETTING: Final[Mapping[tuple[str, str], object]] = {
    ("planner", "footprint"): "rect",
    ("arm", "set_down_slow_m"): 0.0,
}
# What a device event's recorded payload carries about its recording rather than about the event.
_EVENT_RECORD_KEYS: Final = frozenset({"at_state", "at_transitions", "at_device_commands", "t_read", "state"})


@dataclass(frozen=True, slots=True)
class RecordedSession:
    """One job's recording, ready to replay."""

    path: Path
    read: RecordingRead  # compact, of the topics a replay reads (``replayed_topic``); every topic counted
    header: Mapping[str, object]
    config: Config
    backend: str  # the scene's backend name: sim-kinematic, sim-mujoco or hardware
    scene: Mapping[str, object]
    job: Mapping[str, object]
    clock: Mapping[str, object]
    start_ns: int  # the job's start transition
    start_monotonic: float  # the same moment on the recorded session's monotonic clock
    streams: Mapping[str, tuple[Recorded, ...]]  # by topic suffix: input/joints, output/follow, ...
    trace: Trace
    mono_offset_s: float  # recorded now() minus recorded monotonic time (the clocks' fixed difference)
    # The recorded monotonic time of each transition from the job's start on (the start's own first), and
    # of the start of each device command the job gave since, in order: where commands and events fell.
    transition_monos: tuple[float, ...] = ()
    device_command_monos: tuple[float, ...] = ()
    # The device events (``Backend.on_event``) as the job heard them, in order: recorded as such
    # (``input/device_event``), or for an older recording taken from its ``events``.
    device_events: tuple[Recorded, ...] = ()
    # The inputs served by the time of their read, by stream (``TIMED_INPUTS``).
    timed: Mapping[str, TimedInputs] = field(default_factory=dict)
    # The gripper as the telemetry read it, served to the replay's telemetry likewise.
    gripper: GripperTelemetry = field(default_factory=GripperTelemetry)

    @property
    def simulated(self) -> bool:
        return header_part(self.clock, HeaderClock).source == "simulated"

    def with_streams(self, streams: Mapping[str, tuple[Recorded, ...]]) -> RecordedSession:
        """This session with ``streams`` in place of its own (the others kept), its ``timed`` inputs taken
        from them anew (each of their records decoded)."""
        merged = {**self.streams, **streams}
        facts = _no_facts()
        for topic, f in facts.items():
            for r in merged.get(topic, ()):
                m = r.message
                if m is not None:
                    f.add(r, m)
        return dataclasses.replace(self, streams=merged, timed=_timed_of(facts, self.mono_offset_s))

    @property
    def world(self) -> str:
        """What recorded it: ``kinematic``, ``mujoco`` (a simulated cell) or ``hardware``."""
        return RECORDED_BACKENDS[self.backend]

    @property
    def cut(self) -> str | None:
        """Why the recording ends early (a crash, a full disk), or None when it was finished."""
        if not self.read.truncated:
            return None
        return self.read.cut_reason or "the file ends early"

    @property
    def end_s(self) -> float:
        """The last recorded moment, from the job's start."""
        end = self.read.end_ns if self.read.end_ns is not None else self.start_ns
        return (end - self.start_ns) / 1e9

    def commands(self) -> list[Recorded]:
        """The operator's commands that changed something, in the order received."""
        return [
            r
            for r in self.streams.get("input/command", ())
            if isinstance(r.message, Command) and r.message.verb in REPLAYED_VERBS
        ]

    def starting_command(self) -> Recorded | None:
        """The operator's ``start`` that began the job (the first one answered ok; it may be logged after the
        start transition, as its reply comes after it), or None for a ``dishbot run --once`` job."""
        for r in self.commands():
            command = r.message
            assert isinstance(command, Command)  # (commands() keeps only those)
            reply = command.reply
            if command.verb == "start" and not isinstance(reply, UnsetType) and reply_of(reply).ok is True:
                return r
        return None

    def later_commands(self) -> list[Recorded]:
        """The operator's commands after the one that started the job, to be sent again in the job."""
        commands = self.commands()
        starting = self.starting_command()
        if starting is None:
            return [r for r in commands if r.t_ns > self.start_ns]
        return commands[commands.index(starting) + 1 :]

    def monotonic_of(self, r: Recorded) -> float:
        """The recorded monotonic time of a command or a device event (when the daemon took it)."""
        return _monotonic(_position(r.payload), r.t_ns / 1e9 - self.mono_offset_s)

    def anchor(self, r: Recorded) -> Anchor:
        """Where ``r`` (a command or a device event) fell in the job: as recorded with it (``at_*``), else
        from the times of the transitions and device commands before it."""
        position = _position(r.payload)
        t = _monotonic(position, r.t_ns / 1e9 - self.mono_offset_s)
        n, m = position.at_transitions, position.at_device_commands
        if isinstance(n, UnsetType) or isinstance(m, UnsetType):
            n = bisect.bisect_left(self.transition_monos, t)
            m = bisect.bisect_left(self.device_command_monos, t)
        n = max(0, min(n, len(self.transition_monos)))
        m = max(0, min(m, len(self.device_command_monos)))
        base = max(
            self.transition_monos[n - 1] if n else self.start_monotonic,
            self.device_command_monos[m - 1] if m else self.start_monotonic,
        )
        return Anchor(n, m, max(0.0, t - base))

    def device_event_payload(self, r: Recorded) -> dict[str, object]:
        """A recorded device event as the driver handed it (without what its record added)."""
        return {k: v for k, v in r.payload.items() if k not in _EVENT_RECORD_KEYS}

    def start_payload(self) -> bytes:
        """The ``start`` command that began the job: as received when it came over Zenoh, else rebuilt from
        the header (a ``dishbot run --once`` job)."""
        starting = self.starting_command()
        if starting is not None and isinstance(starting.message, Command):
            return starting.message.payload.encode()
        body: dict[str, object] = {}
        job = header_part(self.job, HeaderJob)
        if job.mugs is not None and not isinstance(job.mugs, UnsetType):
            # The mugs go back as recorded, every key of theirs (the view keeps only what readers take):
            # the daemon validates the start body it is sent.
            body["mugs"] = self.job["mugs"]
        if not isinstance(job.planner_overrides, UnsetType) and job.planner_overrides:
            body["planner"] = dict(job.planner_overrides)
        return json.dumps(body).encode()

    @classmethod
    def load(cls, path: Path) -> RecordedSession:
        """Read ``path``; ``ReplayError`` (one line) when it is not a job recording dishbot can replay."""
        try:
            read = read_messages(path, keep=replayed_topic, compact=True)
        except RecordingError as e:
            raise ReplayError(str(e)) from e
        messages = list(read.messages)
        if not messages or messages[0].topic != HEADER_TOPIC:
            raise ReplayError(f"{path}: not a dishbot recording (no {HEADER_TOPIC} message first)")
        header = messages[0].payload
        # The header's documents are checked here, raw, for the one-line errors below (a view of a malformed
        # document is only empty); from here on they are read through their views (``wire.messages.Header*``).
        scene, job, clock, file = (header.get(k) for k in ("scene", "job", "clock", "file"))
        config_doc = header.get("config")
        if not isinstance(config_doc, Mapping) or not isinstance(scene, Mapping):
            raise ReplayError(f"{path}: the session header has no config or scene")
        if (isinstance(file, Mapping) and file.get("kind") != "job") or not isinstance(job, Mapping):
            raise ReplayError(f"{path}: an idle recording holds no job to replay; give a -job.mcap file")
        if clock is not None and not isinstance(clock, Mapping):
            raise ReplayError(f"{path}: the session header's clock is {_shown(clock)}, not a table")
        if isinstance(clock, Mapping) and clock.get("source") == "simulated":
            _check_wall_start(path, clock.get("wall_start"))
        backend = str(scene.get("backend", ""))
        if backend not in RECORDED_BACKENDS:
            raise ReplayError(
                f"{path}: recorded on the {backend or 'unknown'} backend; a replay knows "
                f"{', '.join(RECORDED_BACKENDS)}"
            )
        try:
            # Over today's defaults, so that a recording made before a setting existed still loads; the
            # robot's own Zenoh settings (endpoints, credentials on its disk) are the replay's business.
            # A default that changed is the one the recording was made with (``_BEFORE_SETTING``).
            for (table, key), then in _BEFORE_SETTING.items():
                recorded = config_doc.get(table)
                if isinstance(recorded, Mapping) and key not in recorded:
                    config_doc = {**config_doc, table: {**recorded, key: then}}
            config = load_config(overrides={**config_doc, "zenoh": {}})
        except ConfigError as e:
            raise ReplayError(f"{path}: the recorded config does not load: {e}") from e
        start = job_start(messages)
        if start is None:
            raise ReplayError(f"{path}: the job never started (no start transition recorded)")
        start_ns = start.log_time_ns
        streams: dict[str, list[Recorded]] = {}
        # The timed inputs as decoded here (once: the check, and what they are served by).
        timed_facts = _no_facts()
        gripper = _GripperFacts()
        suffixes: dict[str, str] = {}  # one string per topic, not one per record
        for m in messages[1:]:
            suffix = suffixes.get(m.topic) or suffixes.setdefault(m.topic, topic_suffix(m.topic))
            if suffix == "gripper":
                gripper.add(m)
            elif suffix.startswith(("input/", "output/")) or suffix == "plan":
                declared = None if suffix in _UNTYPED else TOPICS.get(suffix)
                raw = m.raw
                record = (
                    Recorded(suffix, m.log_time_ns, raw=raw, declared=declared)
                    if raw is not None
                    else Recorded(suffix, m.log_time_ns, m.payload, declared=declared)
                )
                try:
                    # Checked here (decoded straight from the bytes), decoded again when served.
                    message = record.message if declared is not None else None
                except BadMessage as e:
                    raise ReplayError(f"{path}: {e}") from None
                streams.setdefault(suffix, []).append(record)
                facts = timed_facts.get(suffix)
                if facts is not None and message is not None:
                    facts.add(record, message)
        # (A job that ended before its first move has no follow, but its other device commands.)
        if "input/joints" in streams and not any(k.startswith("output/") for k in streams):
            raise ReplayError(
                f"{path}: recorded by an older dishbot that did not keep the device commands; record it again"
            )
        mono_offset = _mono_offset(streams.get("input/joints", []), clock)
        start_monotonic = _start_monotonic(start, streams.get("input/joints", []), clock)
        simulated = header_part(clock, HeaderClock).source == "simulated"  # (wall_start checked above)
        transitions: list[float] = []
        # An older recording's device events (no ``input/device_event``), rebuilt from its ``events``: the
        # event as published, its log time, its read time and the job's position then (``InputPosition``).
        older: list[tuple[Mapping[str, object], int, float, int, int]] = []
        started = False
        same_instant: list[float] = []  # device commands recorded so far, by their start
        for m in messages:
            suffix = topic_suffix(m.topic)
            if suffix in _DEVICE_COMMAND_TOPICS:
                t_start = _started(m.payload)
                if t_start is not None:
                    same_instant.append(t_start)
            if suffix != "events":
                continue
            started = started or m is start
            if not started:
                continue
            event_payload = m.payload  # (decoded once: a compact read decodes at each ``payload``)
            try:
                kind = convert(event_payload, EventKind, name=suffix)
            except BadMessage:  # not an event: neither a transition nor a device's
                continue
            if kind.kind == "transition":
                t_device = _position(event_payload).t_device
                logged = m.log_time_ns / 1e9 - mono_offset
                transitions.append(logged if isinstance(t_device, UnsetType) else float(t_device))
            elif "device" in event_payload and kind.kind != "fault_injected":
                # An older recording's device event: its ``t_device`` is the driver's clock, which on a
                # simulated session is the daemon's; on the wall clock its log time says when it came.
                # It came after the transitions published before it (``events`` is in order) ...
                t_device = _position(event_payload).t_device
                logged = m.log_time_ns / 1e9 - mono_offset
                t_read = float(t_device) if simulated and not isinstance(t_device, UnsetType) else logged
                # ... and after the device commands begun before it, or at the same instant when recorded
                # before it (the call that failed as the driver said so), not those that answered it.
                at_same = sum(
                    1 for c in same_instant if start_monotonic - 1e-9 <= c and abs(c - t_read) <= 1e-9
                )
                older.append((event_payload, m.log_time_ns, t_read, len(transitions), at_same))
        commands = sorted(
            t
            for topic in _DEVICE_COMMAND_TOPICS
            for r in streams.get(topic, ())
            if (t := _started(r.payload)) is not None and t >= start_monotonic - 1e-9
        )
        recorded_events = streams.get("input/device_event", [])
        derived_events = [
            Recorded(
                "events",
                t_ns,
                {
                    **event,
                    "t_read": t_read,
                    "at_transitions": n,
                    "at_device_commands": at_same + bisect.bisect_left(commands, t_read - 1e-9),
                },
            )
            for event, t_ns, t_read, n, at_same in older
        ]
        return cls(
            path=path,
            read=read,
            header=header,
            config=config,
            backend=backend,
            scene=scene,
            job=job,
            clock=clock if isinstance(clock, Mapping) else {},
            start_ns=start_ns,
            start_monotonic=start_monotonic,
            streams={k: tuple(v) for k, v in streams.items()},
            trace=trace_of(read, start_ns=start_ns),
            mono_offset_s=mono_offset,
            transition_monos=tuple(transitions),
            device_command_monos=tuple(commands),
            device_events=tuple(r for r in (recorded_events or derived_events) if r.t_ns >= start_ns),
            timed=_timed_of(timed_facts, mono_offset),
            gripper=gripper.telemetry(mono_offset),
        )


# The simulated clock's wall start a header may hold: from 2000 to 2100 (seconds since 1970). Another value
# is a damaged or forged header, and would put every log time out of what MCAP and the clock can hold.
WALL_START_RANGE: Final = (946_684_800.0, 4_102_444_800.0)


def _check_wall_start(path: Path, value: object) -> None:
    low, high = WALL_START_RANGE
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ReplayError(
            f"{path}: the session header's clock.wall_start is {_shown(value)}; a simulated session's "
            "clock needs its wall-clock start (seconds since 1970)"
        )
    if not math.isfinite(value) or not low <= value <= high:
        raise ReplayError(
            f"{path}: the session header's clock.wall_start {value:g} is out of range; allowed "
            f"[{low:.0f}, {high:.0f}] (2000-2100, seconds since 1970)"
        )


def _shown(value: object) -> str:
    return "missing" if value is None else repr(value)


def _position(payload: Mapping[str, object]) -> InputPosition:
    """Where an input fell (``InputPosition``). A recorded position that is not one (a flag where a count
    goes) is not taken, and the input is placed by its times alone; times that are not numbers are not
    taken either (it is placed by its log time then)."""
    try:
        return view(payload, InputPosition)
    except BadMessage:
        pass
    try:
        return view({k: v for k, v in payload.items() if k in ("t_read", "t_device")}, InputPosition)
    except BadMessage:
        return InputPosition()


def _monotonic(position: InputPosition, logged: float) -> float:
    """The driver's time of an input: its ``t_read``, else its ``t_device``, else ``logged``."""
    for t in (position.t_read, position.t_device):
        if not isinstance(t, UnsetType) and math.isfinite(t):
            return float(t)
    return logged


def _started(payload: Mapping[str, object]) -> float | None:
    """When a device command began (``Started``), or None when its record does not say."""
    try:
        t = view(payload, Started).t_start
    except BadMessage:
        return None
    return None if isinstance(t, UnsetType) else float(t)


def _start_monotonic(start: RecordedMessage, joints: Sequence[Recorded], clock: object) -> float:
    """The monotonic time of the job's start: as the transition says (``t_device``), else from its log time
    and the clocks' difference."""
    event = start.decoded(Event)
    t = event.t_device if event is not None else UNSET
    if not isinstance(t, UnsetType):
        return float(t)
    return start.log_time_ns / 1e9 - _mono_offset(joints, clock)


def _mono_offset(joints: Sequence[Recorded], clock: object) -> float:
    """How far the session's ``now()`` is ahead of its monotonic clock: the simulated clock's wall start,
    or on the wall clock the median over the joint reads (each carries both)."""
    view = header_part(clock, HeaderClock)
    if view.source == "simulated" and not isinstance(view.wall_start, UnsetType):
        return float(view.wall_start)
    diffs = [
        r.t_ns / 1e9 - float(r.message.t_read)
        for r in joints
        if isinstance(r.message, InputJoints) and not isinstance(r.message.t_read, UnsetType)
    ]
    return statistics.median(diffs) if diffs else math.nan
