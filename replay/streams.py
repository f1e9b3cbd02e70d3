"""Replaying a recorded session: its driver-boundary inputs as a timeline, faults injected, served back.

A recording holds what the drivers handed the daemon (servo feedback, force readings, grasp results,
observations of the counter). ``Timeline.from_recording`` pulls those inputs out as named streams ordered
in time (seconds from the start of the recording). ``FaultPlan`` rewrites a timeline deterministically —
drop a window, delay it, spike or corrupt a field, add seeded noise, cut a stream or the whole session — so
a test can ask "what does the daemon do when the force sensor goes quiet during the flip?" against a real
session. ``ReplayForceSensor`` and ``ReplayMugObserver`` implement the driver and perception seams over a
timeline and a ``ReplayClock`` that the test (or a replay runner) steps.

The decoders read the record formats ``daemon.backend.recorded`` writes; a test holds the two together.
"""

from __future__ import annotations

import abc
import bisect
import copy
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Final, Generic, TypeVar

import numpy as np
import zenoh

from drivers.errors import SensorFault
from drivers.interfaces import ForceReading, JointState
from perception.interfaces import Detection, Observation
from recorder import HEADER_TOPIC, read_messages
from recorder.errors import RecordingError
from replay.errors import ReplayError

# Stream name -> Zenoh key expression selecting its topics. The daemon records what crosses the driver
# boundary under ``dishbot/<robot_id>/input/<kind>`` (see ``daemon.backend.recorded``).
DEFAULT_STREAMS: Final[Mapping[str, str]] = {
    "joints": "dishbot/*/input/joints",
    "force": "dishbot/*/input/force",
    "holding": "dishbot/*/input/holding",
    "grasp": "dishbot/*/input/grasp",
    "observations": "dishbot/*/input/observation",
}


# --- record formats at the driver boundary (written by ``daemon.backend.recorded``) -------------------------


def decode_force(payload: Mapping[str, object], *, t: float) -> ForceReading:
    """A force sample stamped with replay time ``t``.

    Raises ``ValueError`` naming the field when the payload is not a force sample (a corrupted record).
    """
    return ForceReading(
        t=t, force_n=_number(payload, "force_n"), raw=_integer(payload, "raw"), seq=_integer(payload, "seq")
    )


def decode_observation(payload: Mapping[str, object], *, t: float) -> Observation:
    """An observation stamped with replay time ``t``; ``ValueError`` naming the field when malformed."""
    items = payload.get("mugs")
    if not isinstance(items, list):
        raise ValueError(f"mugs is {items!r}, not a list")
    detections = []
    for i, item in enumerate(items):
        if not isinstance(item, Mapping):
            raise ValueError(f"mugs.{i} is {item!r}, not an object")
        try:
            detections.append(
                Detection(
                    type=_text(item, "type"),
                    x_m=_number(item, "x_m"),
                    y_m=_number(item, "y_m"),
                    upside_down=_flag(item, "upside_down"),
                    handle_yaw_rad=_number(item, "handle_yaw_rad"),
                    confidence=_number(item, "confidence"),
                    mug_id=str(item.get("id", "")),
                    handle_seen=_flag(item, "handle_seen") if "handle_seen" in item else True,
                )
            )
        except ValueError as e:
            raise ValueError(f"mugs.{i}.{e}") from e
    meta = payload.get("meta", {})
    if not isinstance(meta, Mapping):
        raise ValueError(f"meta is {meta!r}, not an object")
    return Observation(t=t, detections=tuple(detections), meta={str(k): str(v) for k, v in meta.items()})


def decode_joints(payload: Mapping[str, object], *, t: float) -> JointState:
    """Servo feedback stamped with replay time ``t``; ``ValueError`` naming the field when malformed."""
    names = payload.get("names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"names is {names!r}, not a list of joint names")
    vectors = {key: _vector(payload, key, len(names)) for key in ("position_rad", "velocity_rad_s", "load")}
    return JointState(
        t=t,
        names=tuple(names),
        position_rad=vectors["position_rad"],
        velocity_rad_s=vectors["velocity_rad_s"],
        load=vectors["load"],
    )


def _number(payload: Mapping[str, object], key: str) -> float:
    value = payload.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{key} is {value!r}, not a finite number")
    return float(value)


def _integer(payload: Mapping[str, object], key: str) -> int:
    value = payload.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{key} is {value!r}, not an integer")
    return value


def _text(payload: Mapping[str, object], key: str) -> str:
    value = payload.get(key)
    if not isinstance(value, str):
        raise ValueError(f"{key} is {value!r}, not a string")
    return value


def _flag(payload: Mapping[str, object], key: str) -> bool:
    value = payload.get(key)
    if not isinstance(value, bool):
        raise ValueError(f"{key} is {value!r}, not a boolean")
    return value


def _vector(payload: Mapping[str, object], key: str, n: int) -> tuple[float, ...]:
    values = payload.get(key)
    if not isinstance(values, list) or len(values) != n:
        raise ValueError(f"{key} is {values!r}, not a list of {n} numbers")
    return tuple(_number({key: v}, key) for v in values)


# --- timeline ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TimedInput:
    """One recorded input: when it arrives in replay (seconds from the start), its topic and payload."""

    t_s: float
    topic: str
    payload: Mapping[str, object]
    log_time_ns: int  # as recorded; unchanged by faults


@dataclass(frozen=True, slots=True)
class Timeline:
    """Driver-boundary inputs of one session as named streams, each ordered by replay time.

    ``end_s`` is where the session ends (its last message, or a cut); ``truncated`` says the recording
    itself was cut (crash, partial copy); ``faults`` lists the faults applied, in order.
    """

    start_ns: int
    end_s: float
    streams: Mapping[str, tuple[TimedInput, ...]]
    header: Mapping[str, object] | None = None
    truncated: bool = False
    faults: tuple[str, ...] = ()

    @classmethod
    def from_recording(cls, path: Path, *, streams: Mapping[str, str] = DEFAULT_STREAMS) -> Timeline:
        """Read the inputs of ``streams`` (name -> key expression, ``*``/``**`` allowed) from a recording.

        Reads finished and cut recordings alike. A topic may feed several streams. Raises ``ReplayError``
        for an invalid key expression and ``RecordingError`` when the file is not a recording.
        """
        selectors = {name: _key_expr(name, expr) for name, expr in streams.items()}
        matches: dict[str, list[str]] = {}

        def streams_of(topic: str) -> list[str]:
            if topic not in matches:
                key = _topic_key(topic)
                found = [] if key is None else [n for n, sel in selectors.items() if sel.includes(key)]
                matches[topic] = found
            return matches[topic]

        rec = read_messages(path, keep=lambda topic: topic == HEADER_TOPIC or bool(streams_of(topic)))
        if rec.start_ns is None or rec.end_ns is None:
            raise RecordingError(f"{path}: holds no messages to replay")
        start = rec.start_ns
        collected: dict[str, list[TimedInput]] = {name: [] for name in streams}
        for message in rec:
            for name in streams_of(message.topic):
                t = (message.log_time_ns - start) / 1e9
                collected[name].append(TimedInput(t, message.topic, message.payload, message.log_time_ns))
        return cls(
            start_ns=start,
            end_s=(rec.end_ns - start) / 1e9,
            streams={name: _ordered(items) for name, items in collected.items()},
            header=rec.header,
            truncated=rec.truncated,
        )

    def stream(self, name: str) -> tuple[TimedInput, ...]:
        """One stream's inputs in replay order; ``ReplayError`` naming the known streams when unknown."""
        try:
            return self.streams[name]
        except KeyError as e:
            raise ReplayError(
                f"no stream {name!r} in this timeline; it has: {', '.join(self.streams)}"
            ) from e

    def merged(self) -> list[tuple[str, TimedInput]]:
        """Every input of every stream as (stream, input), in replay order (ties keep stream order)."""
        pairs = [(name, item) for name, items in self.streams.items() for item in items]
        return sorted(pairs, key=lambda pair: pair[1].t_s)


def _key_expr(name: str, expr: str) -> zenoh.KeyExpr:
    try:
        return zenoh.KeyExpr(expr)
    except zenoh.ZError as e:
        raise ReplayError(f"stream {name!r}: {expr!r} is not a valid Zenoh key expression") from e


def _topic_key(topic: str) -> zenoh.KeyExpr | None:
    try:
        return zenoh.KeyExpr(topic)
    except zenoh.ZError:  # a topic that is no key expression (a foreign file) matches no stream
        return None


def _ordered(items: Sequence[TimedInput]) -> tuple[TimedInput, ...]:
    return tuple(sorted(items, key=lambda item: item.t_s))


# --- faults -----------------------------------------------------------------------------------------------

Streams = dict[str, tuple[TimedInput, ...]]


@dataclass(frozen=True, slots=True)
class Fault(abc.ABC):
    """One rewrite of a timeline's streams and end time. ``apply`` never changes its input."""

    @abc.abstractmethod
    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]: ...

    @abc.abstractmethod
    def describe(self) -> str:
        """One line naming the fault, its stream and its window, as listed in ``Timeline.faults``."""


@dataclass(frozen=True, slots=True)
class Drop(Fault):
    """The stream loses every input in [start_s, end_s): a sensor or link outage."""

    stream: str
    start_s: float
    end_s: float

    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]:
        items = _stream_of(streams, self.stream)
        hit = _window(items, self.start_s, self.end_s, self.describe())
        return {**streams, self.stream: tuple(x for i, x in enumerate(items) if i not in hit)}, end_s

    def describe(self) -> str:
        return f"drop {self.stream} {_span(self.start_s, self.end_s)}"


@dataclass(frozen=True, slots=True)
class Delay(Fault):
    """Inputs in [start_s, end_s) arrive ``by_s`` later, behind newer ones if overtaken: a stalled bus."""

    stream: str
    start_s: float
    end_s: float
    by_s: float

    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]:
        items = _stream_of(streams, self.stream)
        hit = _window(items, self.start_s, self.end_s, self.describe())
        moved = [replace(x, t_s=x.t_s + self.by_s) if i in hit else x for i, x in enumerate(items)]
        return {**streams, self.stream: _ordered(moved)}, max(end_s, max(x.t_s for x in moved))

    def describe(self) -> str:
        return f"delay {self.stream} {_span(self.start_s, self.end_s)} by {self.by_s:g} s"


@dataclass(frozen=True, slots=True)
class Spike(Fault):
    """The first input at or after ``at_s`` carries ``value`` in ``field`` (a dotted path): a glitch."""

    stream: str
    at_s: float
    field: str
    value: object

    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]:
        items = list(_stream_of(streams, self.stream))
        index = bisect.bisect_left([x.t_s for x in items], self.at_s - 1e-9)
        if index == len(items):
            raise ReplayError(f"{self.describe()}: the stream has no input at or after {self.at_s:g} s")
        items[index] = _with_field(items[index], self.field, lambda _old: self.value, self.describe())
        return {**streams, self.stream: tuple(items)}, end_s

    def describe(self) -> str:
        return f"spike {self.stream}.{self.field}={self.value!r} at {self.at_s:g} s"


@dataclass(frozen=True, slots=True)
class Corrupt(Fault):
    """Every input in [start_s, end_s) carries ``value`` in ``field``: a stuck or garbage-sending sensor."""

    stream: str
    start_s: float
    end_s: float
    field: str
    value: object

    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]:
        items = _stream_of(streams, self.stream)
        hit = _window(items, self.start_s, self.end_s, self.describe())
        what = self.describe()
        out = tuple(
            _with_field(x, self.field, lambda _old: self.value, what) if i in hit else x
            for i, x in enumerate(items)
        )
        return {**streams, self.stream: out}, end_s

    def describe(self) -> str:
        return f"corrupt {self.stream}.{self.field}={self.value!r} {_span(self.start_s, self.end_s)}"


@dataclass(frozen=True, slots=True)
class Noise(Fault):
    """Gaussian noise (``sigma``, seeded) added to a numeric ``field`` in [start_s, end_s)."""

    stream: str
    start_s: float
    end_s: float
    field: str
    sigma: float
    seed: int

    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]:
        items = _stream_of(streams, self.stream)
        hit = sorted(_window(items, self.start_s, self.end_s, self.describe()))
        draws = dict(
            zip(hit, np.random.default_rng(self.seed).normal(0.0, self.sigma, len(hit)), strict=True)
        )
        what = self.describe()

        def noisy(i: int, x: TimedInput) -> TimedInput:
            return _with_field(x, self.field, lambda old: _add(old, float(draws[i]), what), what)

        return {
            **streams,
            self.stream: tuple(noisy(i, x) if i in draws else x for i, x in enumerate(items)),
        }, end_s

    def describe(self) -> str:
        window = _span(self.start_s, self.end_s)
        return f"noise {self.stream}.{self.field} sigma={self.sigma:g} seed={self.seed} {window}"


@dataclass(frozen=True, slots=True)
class Cut(Fault):
    """Nothing arrives at or after ``at_s`` on ``stream`` (a dead sensor), or on any stream when None."""

    at_s: float
    stream: str | None = None

    def apply(self, streams: Streams, end_s: float) -> tuple[Streams, float]:
        names = list(streams) if self.stream is None else [self.stream]
        out = dict(streams)
        for name in names:
            out[name] = tuple(x for x in _stream_of(streams, name) if x.t_s < self.at_s)
        return out, min(end_s, self.at_s) if self.stream is None else end_s

    def describe(self) -> str:
        return f"cut {self.stream or 'all streams'} at {self.at_s:g} s"


@dataclass(frozen=True, slots=True)
class FaultPlan:
    """Faults applied to a timeline in the order they were added; the same plan always gives the same result.

    Times are seconds from the start of the recording, as the stream carries them when the fault is applied
    (a delay moves inputs for the faults after it). A fault whose window holds no input is an error, so a
    test cannot pass because its fault missed.
    """

    faults: tuple[Fault, ...] = ()

    def drop(self, stream: str, start_s: float, end_s: float) -> FaultPlan:
        _check_window(start_s, end_s)
        return self._with(Drop(stream, start_s, end_s))

    def delay(self, stream: str, start_s: float, end_s: float, *, by_s: float) -> FaultPlan:
        _check_window(start_s, end_s)
        if not (math.isfinite(by_s) and by_s > 0.0):
            raise ReplayError(f"delay by_s must be a positive number of seconds, got {by_s!r}")
        return self._with(Delay(stream, start_s, end_s, by_s))

    def spike(self, stream: str, at_s: float, field: str, value: object) -> FaultPlan:
        _check_time("spike at_s", at_s)
        _check_field(field)
        return self._with(Spike(stream, at_s, field, value))

    def corrupt(self, stream: str, start_s: float, end_s: float, field: str, value: object) -> FaultPlan:
        _check_window(start_s, end_s)
        _check_field(field)
        return self._with(Corrupt(stream, start_s, end_s, field, value))

    def noise(
        self, stream: str, start_s: float, end_s: float, field: str, *, sigma: float, seed: int
    ) -> FaultPlan:
        _check_window(start_s, end_s)
        _check_field(field)
        if not (math.isfinite(sigma) and sigma > 0.0):
            raise ReplayError(f"noise sigma must be a positive number, got {sigma!r}")
        return self._with(Noise(stream, start_s, end_s, field, sigma, seed))

    def cut(self, at_s: float, stream: str | None = None) -> FaultPlan:
        _check_time("cut at_s", at_s)
        return self._with(Cut(at_s, stream))

    def apply(self, timeline: Timeline) -> Timeline:
        """A new timeline with every fault applied in order; the input timeline is left as it was."""
        streams: Streams = dict(timeline.streams)
        end_s = timeline.end_s
        for fault in self.faults:
            streams, end_s = fault.apply(streams, end_s)
        return replace(
            timeline,
            streams=streams,
            end_s=end_s,
            faults=timeline.faults + tuple(f.describe() for f in self.faults),
        )

    def _with(self, fault: Fault) -> FaultPlan:
        return FaultPlan((*self.faults, fault))


def _check_time(what: str, t: float) -> None:
    if not (math.isfinite(t) and t >= 0.0):
        raise ReplayError(f"{what} must be a time in seconds >= 0, got {t!r}")


def _check_window(start_s: float, end_s: float) -> None:
    _check_time("fault start_s", start_s)
    _check_time("fault end_s", end_s)
    if end_s <= start_s:
        raise ReplayError(f"fault window [{start_s:g}, {end_s:g}) s is empty; end_s must be after start_s")


def _check_field(path: str) -> None:
    if not path or any(not part for part in path.split(".")):
        raise ReplayError(f"fault field {path!r} must be a dotted path such as 'force_n' or 'mugs.0.x_m'")


def _stream_of(streams: Streams, name: str) -> tuple[TimedInput, ...]:
    try:
        return streams[name]
    except KeyError as e:
        raise ReplayError(f"fault names stream {name!r}; the timeline has: {', '.join(streams)}") from e


def _window(items: Sequence[TimedInput], start_s: float, end_s: float, what: str) -> set[int]:
    hit = {i for i, x in enumerate(items) if start_s <= x.t_s < end_s}
    if not hit:
        span = f"{items[0].t_s:g}..{items[-1].t_s:g} s" if items else "nothing"
        raise ReplayError(f"{what}: no input in that window (the stream spans {span})")
    return hit


def _span(start_s: float, end_s: float) -> str:
    return f"[{start_s:g}, {end_s:g}) s"


def _with_field(item: TimedInput, path: str, change: Callable[[object], object], what: str) -> TimedInput:
    """A copy of ``item`` with the value at dotted ``path`` replaced by ``change(old)``."""
    payload = copy.deepcopy(dict(item.payload))
    parts = path.split(".")
    node: object = payload
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        if isinstance(node, dict) and part in node:
            if last:
                node[part] = change(node[part])
            else:
                node = node[part]
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            if last:
                node[int(part)] = change(node[int(part)])
            else:
                node = node[int(part)]
        else:
            raise ReplayError(
                f"{what}: the input at {item.t_s:g} s has no field {'.'.join(parts[: depth + 1])!r}"
            )
    return replace(item, payload=payload)


def _add(old: object, delta: float, what: str) -> float:
    if isinstance(old, bool) or not isinstance(old, int | float):
        raise ReplayError(f"{what}: cannot add noise to {old!r}, which is not a number")
    return float(old) + delta


# --- replay sources ---------------------------------------------------------------------------------------


class ReplayClock:
    """Replay time in seconds from the start of the timeline; only moves forward, only when told to."""

    def __init__(self, start_s: float = 0.0) -> None:
        _check_time("replay clock start_s", start_s)
        self._now = start_s

    def now(self) -> float:
        return self._now

    def advance(self, dt_s: float) -> float:
        """Move forward by ``dt_s`` seconds and return the new time."""
        if not (math.isfinite(dt_s) and dt_s >= 0.0):
            raise ReplayError(f"replay clock can only move forward; got dt_s={dt_s!r}")
        self._now += dt_s
        return self._now

    def set(self, t_s: float) -> None:
        """Jump forward to ``t_s``."""
        if not (math.isfinite(t_s) and t_s >= self._now):
            raise ReplayError(
                f"replay clock can only move forward; it is at {self._now:g} s, asked for {t_s!r}"
            )
        self._now = t_s


T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class _Decoded(Generic[T]):
    """A stream's inputs that parsed, with their times for bisecting, and how many did not parse."""

    times: tuple[float, ...]
    values: tuple[T, ...]
    rejected: tuple[str, ...] = ()

    def latest_index(self, now: float) -> int | None:
        i = bisect.bisect_right(self.times, now) - 1
        return None if i < 0 else i


class ReplayForceSensor:
    """A ``drivers.interfaces.ForceSensor`` serving recorded force samples as the clock passes them.

    ``holding`` is recomputed from the (possibly faulted) force with the live FSR reader's rule: it turns
    on after the force has stayed at or above ``threshold_n`` for ``debounce_s``, and off after it has
    stayed below ``release_n`` as long; so a fault injected into the force reaches the holding decision as
    it would live. Inputs that do not parse (a corrupted field) are rejected as the live serial reader
    rejects a garbled line; ``rejected`` says why.
    """

    def __init__(
        self,
        inputs: Sequence[TimedInput],
        clock: ReplayClock,
        *,
        threshold_n: float,
        release_n: float,
        debounce_s: float,
    ) -> None:
        if not 0.0 <= release_n < threshold_n:
            raise ReplayError(f"release_n {release_n!r} must be in [0, threshold_n={threshold_n!r})")
        if not (math.isfinite(debounce_s) and debounce_s >= 0.0):
            raise ReplayError(f"debounce_s must be a time in seconds >= 0, got {debounce_s!r}")
        self._clock = clock
        times: list[float] = []
        readings: list[tuple[ForceReading, bool]] = []
        rejected: list[str] = []
        holding = False
        pending_since: float | None = None
        for item in inputs:
            try:
                reading = decode_force(item.payload, t=item.t_s)
            except ValueError as e:
                rejected.append(f"force at {item.t_s:g} s: {e}")
                continue
            crossing = reading.force_n < release_n if holding else reading.force_n >= threshold_n
            if not crossing:
                pending_since = None
            elif pending_since is None and debounce_s > 0.0:
                pending_since = item.t_s
            elif pending_since is None or item.t_s - pending_since >= debounce_s:
                holding, pending_since = not holding, None
            times.append(item.t_s)
            readings.append((reading, holding))
        self._decoded = _Decoded(tuple(times), tuple(readings), tuple(rejected))

    @property
    def rejected(self) -> tuple[str, ...]:
        return self._decoded.rejected

    def latest(self) -> ForceReading | None:
        i = self._decoded.latest_index(self._clock.now())
        return None if i is None else self._decoded.values[i][0]

    def holding(self) -> bool:
        i = self._decoded.latest_index(self._clock.now())
        return False if i is None else self._decoded.values[i][1]


class ReplayMugObserver:
    """A ``perception.interfaces.MugObserver`` answering with the newest recorded observation.

    When no observation arrived within ``max_age_s`` before the clock (the stream was dropped or cut, or
    the replay asks before the first one) it raises ``SensorFault``, as a camera that stopped would.
    Observations that do not parse are rejected (``rejected`` says why) and never served.
    """

    def __init__(self, inputs: Sequence[TimedInput], clock: ReplayClock, *, max_age_s: float = 1.0) -> None:
        if not (math.isfinite(max_age_s) and max_age_s > 0.0):
            raise ReplayError(f"max_age_s must be a positive number of seconds, got {max_age_s!r}")
        self._clock = clock
        self._max_age_s = max_age_s
        times: list[float] = []
        observations: list[Observation] = []
        rejected: list[str] = []
        for item in inputs:
            try:
                observations.append(decode_observation(item.payload, t=item.t_s))
            except ValueError as e:
                rejected.append(f"observation at {item.t_s:g} s: {e}")
                continue
            times.append(item.t_s)
        self._decoded = _Decoded(tuple(times), tuple(observations), tuple(rejected))

    @property
    def rejected(self) -> tuple[str, ...]:
        return self._decoded.rejected

    async def observe(self) -> Observation:
        now = self._clock.now()
        i = self._decoded.latest_index(now)
        if i is None or now - self._decoded.times[i] > self._max_age_s:
            raise SensorFault(
                f"replayed camera: no observation in the {self._max_age_s:g} s before t={now:g} s; "
                "the observations stream was dropped, cut or has not started"
            )
        return self._decoded.values[i]
