"""The replay's devices: the simulated cell's, with the recorded inputs served in their place while the
daemon does what it did.

A ``Replayer`` holds the recorded streams and a cursor in each. Each replay device wraps the simulated
cell's device and always drives it too, so that the cell stays where the recording says the robot was;
while the replay is *replaying* it hands the job what the recording holds instead of what the cell says:

- joint feedback, force readings and the holding flag by time: the last one recorded at or before the
  moment the daemon reads (the recording's clock laid over the replay's at the job's start);
- grasp results, observations and placement plans by order: the n-th call gets the n-th recorded result,
  after as long as it took then; a call that failed then fails the same way now;
- the device commands (moves, openings, closes) are compared with the recorded ones as they are given.

The first difference — a device command other than the recorded one, a state the recording did not enter,
an operator command answered otherwise, an injected fault, or the end of a recording cut short — ends
replaying: from then on every device is the simulated cell's alone, started from where the recorded
commands put it (``diverge``).
"""

from __future__ import annotations

import bisect
import contextlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import structlog

import drivers.errors as driver_errors
from daemon.backend import Backend, PlanPlacement
from daemon.clock import SessionClock
from drivers.errors import DriverError
from drivers.interfaces import (
    ArmDriver,
    ForceReading,
    ForceSensor,
    GraspResult,
    GripperDriver,
    GripperState,
    JointState,
    JointTrajectory,
)
from perception.interfaces import Detection, MugObserver, Observation
from planning.placement import PlacementPlanner, PlanOptions, PlanResult, Problem
from replay.session import DeviceCommand, Divergence, Recorded, RecordedSession, device_command

log = structlog.get_logger("replay")

# Reads this close together are the same instant (simulated time is exact; the wall clock never is).
_SAME_S = 1e-7
# Streams served by time, and those served by order (several recorded topics make one stream).
_TIMED = ("input/joints", "input/force", "input/holding")
_ORDERED: Mapping[str, tuple[str, ...]] = {
    "follow": ("output/follow",),
    "open": ("output/gripper",),
    "grasp": ("input/grasp", "input/grasp_failed"),
    "observation": ("input/observation", "input/observe_failed"),
    "plan": ("plan",),
}


class Replayer:
    """The recorded session, its cursors and whether the replay still follows it."""

    def __init__(
        self,
        session: RecordedSession,
        clock: SessionClock,
        *,
        on_diverge: Callable[[Divergence], None] | None = None,
    ) -> None:
        self.session = session
        self.clock = clock
        self.replaying = True
        self.divergence: Divergence | None = None
        self.state = "idle"
        self.served: dict[str, int] = {}
        self._on_diverge = on_diverge
        self._start_now: float | None = None  # the replay's now() at its job's start transition
        self._start_mono = 0.0  # and its monotonic time then
        # Timed inputs by the recorded monotonic time of their read (older recordings: their log time).
        self._timed = {k: list(session.streams.get(k, ())) for k in _TIMED}
        self._timed_t = {k: [self._read_time(r) for r in v] for k, v in self._timed.items()}
        self._ordered: dict[str, list[Recorded]] = {}
        for name, topics in _ORDERED.items():
            items = [r for t in topics for r in session.streams.get(t, ())]
            if name == "open":
                items = [r for r in items if r.payload.get("action") == "open"]
            self._ordered[name] = sorted(items, key=lambda r: r.t_ns)
        self._next = dict.fromkeys(_ORDERED, 0)
        self._cursor: dict[str, int] = {}  # per timed stream: the first record not yet consumed

    # --- time --------------------------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        return self._start_now is not None

    def job_started(self) -> None:
        """The replay's job just entered its first state: lay the recording's clock over the replay's."""
        self._start_now = self.clock.now()
        self._start_mono = self.clock.monotonic()

    def _read_time(self, r: Recorded) -> float:
        t = r.payload.get("t_read")
        if isinstance(t, int | float):
            return float(t)
        return r.t_ns / 1e9 - self.session.mono_offset_s

    def t_s(self) -> float:
        """Seconds since the replay's job started (0 before)."""
        return 0.0 if self._start_now is None else self.clock.now() - self._start_now

    def recorded_monotonic(self) -> float:
        """Now, on the recorded session's monotonic clock (both clocks lined up at the job's start; exact
        arithmetic on small numbers, so that a replay of a simulated session meets every recorded instant
        exactly)."""
        return self.clock.monotonic() - self._start_mono + self.session.start_monotonic

    def replay_monotonic(self, recorded_monotonic: float) -> float:
        """The replay's monotonic time for a recorded one (a device time or the end of a call)."""
        return recorded_monotonic - self.session.start_monotonic + self._start_mono

    async def until_recorded(self, recorded: Recorded, key: str = "t_end") -> None:
        """Wait until the moment a recorded call ended, as the replay's clock lays it."""
        end = recorded.payload.get(key)
        if isinstance(end, int | float) and math.isfinite(end):
            await self.clock.sleep_until(self.replay_monotonic(float(end)))

    # --- following the recording ---------------------------------------------------------------------------

    def diverge(self, what: str, expected: str, got: str) -> None:
        """Stop replaying: the simulated cell takes over from here."""
        if not self.replaying:
            return
        self.replaying = False
        self.divergence = Divergence(self.t_s(), self.state, what, expected, got)
        log.info("replay_diverged", **self.divergence.to_json())
        if self._on_diverge is not None:
            self._on_diverge(self.divergence)

    def serving(self) -> bool:
        """Whether recorded inputs stand in for the cell's now: replaying a started job, within the
        recording (a recording cut short ends replaying where it ends)."""
        if not self.replaying or self._start_now is None:
            return False
        if self.session.cut is not None and self.t_s() > self.session.end_s:
            self.recording_ended()
            return False
        return True

    def recording_ended(self) -> None:
        """A recording cut short has nothing more to serve: not a divergence (the replay did what it did up
        to here); the simulated cell goes on alone until the replay stops at the cut."""
        if self.replaying:
            self.replaying = False
            log.info("replay_recording_ended", t_s=self.t_s(), cut=self.session.cut)

    def latest(self, stream: str) -> Recorded | None:
        """The input of ``stream`` the daemon consumed at this moment: of those recorded at the same time
        , the next in the order they were consumed; else the last one recorded
         before."""
        times = self._timed_t[stream]
        now = self.recorded_monotonic()
        i = max(self._cursor.get(stream, 0), bisect.bisect_left(times, now - _SAME_S))
        if i < len(times) and abs(times[i] - now) <= _SAME_S:
            self._cursor[stream] = i + 1
        else:
            i = bisect.bisect_right(times, now) - 1
            if i < 0:
                return None
        self.served[stream] = self.served.get(stream, 0) + 1
        return self._timed[stream][i]

    def take(self, stream: str, got: str) -> Recorded | None:
        """The next recorded result of ``stream``; at the end of the recording, divergence (None)."""
        items = self._ordered[stream]
        i = self._next[stream]
        if i >= len(items):
            if self.session.cut is not None:
                self.recording_ended()
            else:
                self.diverge(stream, "nothing more recorded", got)
            return None
        self._next[stream] = i + 1
        self.served[stream] = self.served.get(stream, 0) + 1
        return items[i]

    def check(self, recorded: Recorded, asked: DeviceCommand | None) -> bool:
        """Whether the daemon asks a device for what it asked then; divergence when not."""
        expected = device_command(recorded.kind, recorded.payload, 0.0)
        if asked is None or expected is None or not expected.same(asked):
            self.diverge(
                "device",
                expected.describe() if expected else recorded.kind,
                asked.describe() if asked else "?",
            )
            return False
        return True


def replay_backend(backend: Backend, replayer: Replayer) -> Backend:
    """``backend`` (the simulated cell) with its devices, observer and placement behind ``replayer``."""
    return replace(
        backend,
        arm=ReplayArm(backend.arm, replayer),
        gripper=ReplayGripper(backend.gripper, replayer),
        force=ReplayForce(backend.force, replayer),
        observer=ReplayObserver(backend.observer, replayer),
        placement=ReplayPlacement(replayer),
    )


def recorded_failure(text: str) -> BaseException:
    """The driver error a recorded failure names (``ServoFault: servo 3 overload``), raised again: of the
    class it had when that class takes a message, else a ``DriverError`` of the same name."""
    name, _, message = text.partition(": ")
    cls = getattr(driver_errors, name, None)
    if isinstance(cls, type) and issubclass(cls, Exception):
        with contextlib.suppress(TypeError):
            error: BaseException = cls(message)
            return error
    stand_in: type[DriverError] = type(name, (DriverError,), {})
    return stand_in(message)


class ReplayArm:
    def __init__(self, inner: ArmDriver, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._inner.joint_names

    async def read_joints(self) -> JointState:
        live = await self._inner.read_joints()
        if not self._r.serving():
            return live
        rec = self._r.latest("input/joints")
        if rec is None:
            return live
        p = rec.payload
        return JointState(
            t=self._r.clock.monotonic(),
            names=tuple(str(n) for n in _list(p, "names")),
            position_rad=_floats(p, "position_rad"),
            velocity_rad_s=_floats(p, "velocity_rad_s"),
            load=_floats(p, "load"),
        )

    async def follow(self, trajectory: JointTrajectory) -> None:
        asked = device_command(
            "output/follow",
            {"label": trajectory.label, "end_rad": [float(v) for v in trajectory.positions[-1]]}
            if len(trajectory.times)
            else {"label": trajectory.label, "end_rad": []},
            self._r.t_s(),
        )
        rec = self._r.take("follow", asked.describe() if asked else "") if self._r.serving() else None
        if rec is None or not self._r.check(rec, asked):
            await self._inner.follow(trajectory)
            return
        await self._inner.follow(trajectory)  # the cell moves as the robot did
        await self._r.until_recorded(rec)
        _raise_recorded(rec)

    async def stop(self) -> None:
        await self._inner.stop()

    async def relax(self) -> None:
        await self._inner.relax()


class ReplayGripper:
    def __init__(self, inner: GripperDriver, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    async def read(self) -> GripperState:
        return await self._inner.read()

    async def open(self, aperture_m: float | None = None) -> None:
        asked = device_command("output/gripper", {"action": "open", "aperture_m": aperture_m}, self._r.t_s())
        rec = self._r.take("open", asked.describe() if asked else "") if self._r.serving() else None
        if rec is None or not self._r.check(rec, asked):
            await self._inner.open(aperture_m)
            return
        await self._inner.open(aperture_m)
        await self._r.until_recorded(rec)
        _raise_recorded(rec)

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        asked = device_command("input/grasp", {"force_threshold_n": force_threshold_n}, self._r.t_s())
        rec = self._r.take("grasp", asked.describe() if asked else "") if self._r.serving() else None
        live = await self._inner.close_on_mug(
            force_threshold_n=force_threshold_n, min_aperture_m=min_aperture_m
        )
        if rec is None or not self._r.check(rec, asked):
            return live
        await self._r.until_recorded(rec)
        _raise_recorded(rec)
        p = rec.payload
        return GraspResult(
            held=bool(p.get("held")),
            force_n=_float(p, "force_n"),
            aperture_m=_float(p, "aperture_m"),
            reason=str(p.get("reason", "")),
        )

    async def stop(self) -> None:
        await self._inner.stop()


class ReplayForce:
    def __init__(self, inner: ForceSensor, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    def latest(self) -> ForceReading | None:
        live = self._inner.latest()
        if not self._r.serving():
            return live
        rec = self._r.latest("input/force")
        if rec is None:
            return live
        p = rec.payload
        device_t = p.get("t_device")
        t = self._r.replay_monotonic(float(device_t)) if isinstance(device_t, int | float) else 0.0
        raw, seq = p.get("raw"), p.get("seq")
        return ForceReading(
            t=t,
            force_n=_float(p, "force_n"),
            raw=raw if isinstance(raw, int) else 0,
            seq=seq if isinstance(seq, int) else 0,
        )

    def holding(self) -> bool:
        live = self._inner.holding()
        if not self._r.serving():
            return live
        rec = self._r.latest("input/holding")
        return live if rec is None else bool(rec.payload.get("holding"))


class ReplayObserver:
    def __init__(self, inner: MugObserver, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    async def observe(self) -> Observation:
        rec = self._r.take("observation", "a look at the counter") if self._r.serving() else None
        live = await self._inner.observe()  # the cell's camera and detector run as they did
        if rec is None or not self._r.replaying:
            return live
        await self._r.until_recorded(rec)
        _raise_recorded(rec)
        p = rec.payload
        device_t = p.get("t_device")
        meta = p.get("meta")
        return Observation(
            t=self._r.replay_monotonic(float(device_t)) if isinstance(device_t, int | float) else live.t,
            detections=tuple(_detection(d) for d in _list(p, "mugs") if isinstance(d, Mapping)),
            depth_preview=live.depth_preview,
            meta={str(k): str(v) for k, v in meta.items()} if isinstance(meta, Mapping) else {},
        )


class ReplayPlacement:
    """Placement planning as the recording has it: the n-th plan recorded, when it was made for the same
    mugs; else (and after divergence) the planner itself."""

    def __init__(self, replayer: Replayer) -> None:
        self._r = replayer

    async def __call__(
        self, planner: PlacementPlanner, problem: Problem, options: PlanOptions, run: PlanPlacement
    ) -> PlanResult:
        mugs = sorted(m.id for m in problem.mugs)
        rec = self._r.take("plan", f"a plan for {', '.join(mugs)}") if self._r.serving() else None
        if rec is None:
            return await run(planner, problem, options)
        try:
            result = PlanResult.from_json(rec.payload)
        except ValueError as e:
            self._r.diverge("plan", "a recorded plan", f"an unreadable one ({e})")
            return await run(planner, problem, options)
        planned = sorted([p.id for p in result.placed] + list(result.unplaced))
        if planned != mugs:
            self._r.diverge("plan", f"a plan for {', '.join(planned)}", f"a plan for {', '.join(mugs)}")
            return await run(planner, problem, options)
        return result


def _raise_recorded(rec: Recorded) -> None:
    error = rec.payload.get("error")
    if isinstance(error, str):
        raise recorded_failure(error)


def _list(payload: Mapping[str, object], key: str) -> Sequence[object]:
    value = payload.get(key)
    return value if isinstance(value, list) else []


def _floats(payload: Mapping[str, object], key: str) -> tuple[float, ...]:
    return tuple(float(v) for v in _list(payload, key) if isinstance(v, int | float))


def _float(payload: Mapping[str, object], key: str) -> float:
    value = payload.get(key)
    return float(value) if isinstance(value, int | float) else 0.0


def _detection(d: Mapping[str, object]) -> Detection:
    return Detection(
        type=str(d.get("type", "")),
        x_m=_float(d, "x_m"),
        y_m=_float(d, "y_m"),
        upside_down=bool(d.get("upside_down")),
        handle_yaw_rad=_float(d, "handle_yaw_rad"),
        confidence=_float(d, "confidence"),
        mug_id=str(d.get("id", "")),
        handle_seen=bool(d.get("handle_seen", True)),
    )
