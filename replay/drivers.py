"""The replay's devices: the simulated cell's, with the recorded inputs served in their place while the
daemon does what it did.

A ``Replayer`` holds the recorded streams and a cursor in each. Each replay device wraps the simulated
cell's device and drives it with every command too, so that the cell stays where the recording says the
robot was; while the replay is *replaying* it hands the job what the recording holds instead of what the
cell says (and does not read the cell):

- joint feedback, force readings, the holding flag and the telemetry's gripper readings by time: the last
  one recorded at or before the moment the daemon reads (the recording's clock laid over the replay's at
  the job's start); a joint read that failed then fails now, and so does a gripper read or a health poll
  (once each). A recording that says who read each joint sample (``reader``) hands each reader its own:
  the job's own reads by order, the telemetry's by time among its samples;
- grasp results, observations, placement plans and motion plans by order: the n-th call gets the n-th
  recorded result, after as long as it took then; a call that failed then fails the same way now (the
  same driver error class, ``recorded_failure``), and the cell's side of it stops where it ended then; a
  motion plan only while the job asks with the same arguments;
- device events (``ReplayEvents``): the recorded ones, handed over by ``replay.engine`` where they fell in
  the job (``Replayer.reach``: after as many transitions and device commands), the cell's own held back;
- the device commands (moves, openings, closes) are compared with the recorded ones as they are given;
- the stand-in's FSR samples reach its reader without their serial lines (``hand_force_samples``).

The first difference — a device command other than the recorded one, a state the recording did not enter,
an operator command answered otherwise, a motion plan asked for other arguments, an injected fault, or the
end of a recording cut short — ends replaying: from then on every device is the simulated cell's alone,
started from where the recorded commands put it (``diverge``).
"""

from __future__ import annotations

import asyncio
import bisect
import collections
import contextlib
import importlib
import math
import threading
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import replace
from typing import Final, TypeVar, cast

import structlog

from daemon.backend import Backend, EventListener, MotionCalls, PlanPlacement
from daemon.clock import SessionClock, SimulatedClock
from daemon.recorded import JOB_READER, current_joint_reader
from drivers.errors import BusLost, DriverError
from drivers.fsr.protocol import Sample
from drivers.interfaces import (
    ArmDriver,
    DeviceHealth,
    ForceReading,
    ForceSensor,
    GraspResult,
    GripperDriver,
    GripperState,
    JointState,
    JointTrajectory,
)
from perception.interfaces import Detection, MugObserver, Observation
from planning.interfaces import MotionPlanner, MotionRefused
from planning.placement import PlacementPlanner, PlanOptions, PlanResult, Problem
from replay.errors import ReplayError
from replay.session import (
    TIMED_INPUTS,
    Anchor,
    DeviceCommand,
    Divergence,
    Recorded,
    RecordedSession,
    TimedInputs,
    device_command,
)
from wire.messages import (
    UNSET,
    CallFailed,
    Failure,
    Follow,
    Force,
    Grasp,
    GripperCommand,
    Holding,
    InputJoints,
    Message,
    Motion,
    ReadFailed,
    UnsetType,
)
from wire.messages import Detection as RecordedDetection
from wire.messages import Observation as RecordedObservation
from wire.motion import BadMotionRecord, args_digest, result_from_json

T = TypeVar("T")

log = structlog.get_logger("replay")

# Reads this close together are the same instant (simulated time is exact; the wall clock never is).
_SAME_S = 1e-7
# How far ahead of a wall-clock recording's read time the next joint sample not served yet may be and still
# be the one the robot's reader took (it read later than the replay, its computation taking time).
_WALL_READ_S = 0.1
# Streams served by time (a read that failed then fails now): ``replay.session.TIMED_INPUTS``.
# Reads of which only the failures are recorded: each served once, at the first read at or after it.
_FAILURES: Final = ("input/health_failed", "input/gripper_failed")
# Streams served by order (several recorded topics make one stream).
_ORDERED: Mapping[str, tuple[str, ...]] = {
    "follow": ("output/follow",),
    "open": ("output/gripper",),
    "grasp": ("input/grasp", "input/grasp_failed"),
    "observation": ("input/observation", "input/observe_failed"),
    "plan": ("plan",),
    "motion": ("input/motion",),
}
# The driver errors a recording names, by module and name (``error_class``) and by name alone (older
# recordings: ``error`` only): raised again as themselves, so that the daemon treats them as it did.
_ERROR_MODULES: Final = (
    "drivers.errors",
    "drivers.dynamixel.bus",
    "drivers.dynamixel.health",
    "perception.errors",
    "drivers.camera.realsense",
)
# How long (simulated s) a worker thread asking a plan the recorded job never got gives the job to move on
# (the device fault or stop that interrupted the recorded job's computation, handed over first).
_INTERRUPTED_WAIT_S = 1.0
# How often (wall s) a worker thread waiting for the event loop to run what it handed it looks whether the
# loop is gone: only for noticing the end of the replay, never for what happens in it.
_LOOP_GONE_POLL_S = 0.5
# How long a replayed call recorded as cancelled waits for the replay's job to cancel it too (simulated s).
_CANCEL_WAIT_S = 1.0


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
        self._state = "idle"
        self.served: dict[str, int] = {}
        self._on_diverge = on_diverge
        self._start_now: float | None = None  # the replay's now() at its job's start transition
        self._start_mono = 0.0  # and its monotonic time then
        # Timed inputs by the recorded monotonic time of their read (older recordings: their log time), as
        # ``RecordedSession.load`` took them from the messages it decoded (``TimedInputs``).
        self._timed: dict[str, Sequence[Recorded]] = {}
        self._timed_t: dict[str, Sequence[float]] = {}
        # Per timed stream, whether each record is a read that worked (``_wall_joint_read`` looks ahead at
        # it for every joint read).
        self._timed_ok: dict[str, Sequence[bool]] = {}
        for name in TIMED_INPUTS:
            timed = session.timed.get(name, TimedInputs())
            self._timed[name] = timed.records
            self._timed_t[name] = timed.read_times
            self._timed_ok[name] = timed.ok
        joint_readers = session.timed.get("input/joints", TimedInputs()).readers  # who took each sample
        # The holding flags (the daemon reads one at every force poll).
        self._holding = session.timed.get("input/holding", TimedInputs()).holding
        # Joint samples by reader (the job, the telemetry: ``daemon.recorded.joint_reader``), each reader's
        # a timed stream of its own; None for a recording that does not say (an older one): every reader
        # then gets the sample its read time matches among them all.
        self._joint_readers: dict[str, str] | None = None
        if joint_readers and all(reader is not None for reader in joint_readers):
            self._joint_readers = {}
            for reader in sorted({str(reader) for reader in joint_readers}):
                stream = f"input/joints:{reader}"
                self._joint_readers[reader] = stream
                own = [k for k, by in enumerate(joint_readers) if by == reader]
                self._timed[stream] = [self._timed["input/joints"][k] for k in own]
                self._timed_t[stream] = [self._timed_t["input/joints"][k] for k in own]
                self._timed_ok[stream] = [self._timed_ok["input/joints"][k] for k in own]
        # The job's own reads since its start, served by order: the n-th read the replay's job makes gets the
        # n-th the recorded job made (it reads at a point of its work, not at a time: the robot's job read
        # later than the replay's, by as long as its computing took, and the telemetry may have read between).
        job_stream = f"input/joints:{JOB_READER}"
        self._job_reads = [
            r
            for t, r in zip(self._timed_t.get(job_stream, ()), self._timed.get(job_stream, ()), strict=True)
            if t >= session.start_monotonic - _SAME_S
        ]
        self._job_reads_next = 0
        self._ordered: dict[str, list[Recorded]] = {}
        for name, topics in _ORDERED.items():
            items = [r for t in topics for r in session.streams.get(t, ())]
            if name == "open":
                items = [r for r in items if _as(r, GripperCommand).action == "open"]
            self._ordered[name] = sorted(items, key=lambda r: r.t_ns)
        self._next = dict.fromkeys(_ORDERED, 0)
        self._motion_taken: set[int] = set()  # motion records served out of order (``take_motion``)
        self._motion_last = -1  # the latest (in the recording) motion record served
        # The motion records not yet served, by call and arguments digest.
        self._motion_by_args: dict[tuple[str, str], collections.deque[int]] = {}
        for i, r in enumerate(self._ordered["motion"]):
            m = _as(r, Motion)
            self._motion_by_args.setdefault((m.call, m.args_digest), collections.deque()).append(i)
        self._motion_lock = threading.Lock()  # motion plans are asked from the job's worker threads
        self._cursor: dict[str, int] = {}  # per timed stream: the first record not yet consumed
        self._last_served: dict[str, int] = {}  # per timed stream: the latest record served so far
        # Health polls and gripper reads that failed, served once each at or after their time.
        self._failures: dict[str, list[tuple[float, Recorded]]] = {}
        for k in _FAILURES:
            failures = [(self._read_time(r), r) for r in session.streams.get(k, ())]
            self._failures[k] = sorted(failures, key=lambda pair: pair[0])  # (read times taken once)
        self._failures_next = dict.fromkeys(_FAILURES, 0)
        # Where the replay's job is (``JobPosition``): the replay's monotonic time of each transition from
        # its start on and of the start of each device command since.
        self.transition_times: list[float] = []
        self.device_command_times: list[float] = []
        self._moved: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None  # the replay's event loop, from the job's start
        self.events_delivered = 0  # recorded device events handed to the daemon, in recorded order
        # The stand-in is not the recording's own cell (a robot's recording, another simulated world): its
        # side of a served call is cut where the recorded call ended.
        self.other_cell = False
        self.overran_s: float | None = None  # the limit a replay ran past without its job ending
        self.events: ReplayEvents | None = None  # set by the replay backend's device events

    # --- time --------------------------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        return self._start_now is not None

    def job_started(self) -> None:
        """The replay's job just entered its first state: lay the recording's clock over the replay's."""
        self._start_now = self.clock.now()
        self._start_mono = self.clock.monotonic()
        self._loop = asyncio.get_running_loop()

    # --- where the job is ----------------------------------------------------------------------------------

    @property
    def state(self) -> str:
        return self._state

    @state.setter
    def state(self, dest: str) -> None:
        """The replay's job entered ``dest`` (every transition: the job's position moves on)."""
        self._state = dest
        if self.started:
            self.transition_times.append(self.clock.monotonic())
            self._moved_on()

    def device_command(self) -> int:
        """The replay's job gave a device command (a move, an opening, a close, a look, a stop); its number
        in the job (from 0; -1 before the job's start). The device events the recording has where the job
        is now, before its next device command, come first: the job may get to that command sooner than the
        robot did (a stop the stand-in needs no time for)."""
        if not self.started:
            return -1
        m = len(self.device_command_times)
        self._deliver_before_command(m)
        self.device_command_times.append(self.clock.monotonic())
        self._moved_on()
        return m

    async def as_long_as_recorded(self, m: int) -> None:
        """After the job's ``m``-th device command, one the recording keeps no end of (a stop), while the
        replay follows the recording in a stand-in for another cell: the job goes on no sooner than the
        recorded job did after it (at its next transition or device command). The stand-in stops at once;
        a robot's stop can take a while, and what the drivers reported meanwhile comes before what the job
        did next."""
        if m < 0 or not self.other_cell or not self.serving():
            return  # (the recording's own simulated cell stops as it did)
        commands, transitions = self.session.device_command_monos, self.session.transition_monos
        if m >= len(commands):
            return
        after = [t for t in commands[m + 1 : m + 2] if t >= commands[m]]
        n = bisect.bisect_right(transitions, commands[m])
        if n < len(transitions):
            after.append(transitions[n])
        if after:
            await self.clock.sleep_until(self.replay_monotonic(min(after)))

    def _moved_on(self) -> None:
        if self._moved is not None:
            self._moved.set()
            self._moved = None

    # --- device events that came while the job computed ----------------------------------------------------

    def deliver_events_while_computing(self, before_ns: int | None) -> None:
        """From a worker thread computing for the job (a motion plan): hand the daemon now the recorded
        device events that came while the robot computed, those anchored where the job is now and recorded
        before ``before_ns`` (None: before the job moved on), in order. Simulated time stands still while
        the job's thread computes, so their recorded offsets from the anchor would only come after the
        computation: after what the robot did once it was done (a plan published, a move begun)."""
        loop = self._loop
        if loop is None or not self.replaying:
            return
        events, i = self.session.device_events, self.events_delivered
        if i >= len(events) or (before_ns is not None and events[i].t_ns >= before_ns):
            return  # nothing came meanwhile (most plans): no need to wake the loop
        if _on(loop):  # asked on the event loop itself (a plan made inline): nothing to wait for
            self._deliver_anchored_here(before_ns)
            return
        done = threading.Event()

        def deliver() -> None:
            try:
                self._deliver_anchored_here(before_ns)
            finally:
                done.set()

        try:
            loop.call_soon_threadsafe(deliver)
        except RuntimeError:  # the loop is closed: the replay is over
            return
        # The loop runs it while it waits for this thread (the simulated clock looks for callbacks handed
        # over meanwhile), however long that takes on this machine; only a loop that is gone never does.
        while not done.wait(_LOOP_GONE_POLL_S):
            if loop.is_closed() or not loop.is_running():
                return

    def deliver_before_next_command(self) -> None:
        """Hand the daemon the device events the recording has where the job is now, before its next
        device command (a failed call's faults, which the drivers report as it fails)."""
        if self.started:
            self._deliver_before_command(len(self.device_command_times))

    def _deliver_before_command(self, m: int) -> None:
        """Hand the daemon the device events anchored where the job is now that the recording has before
        its ``m``-th device command (from 0)."""
        monos = self.session.device_command_monos
        if not self.replaying or self.events is None or m >= len(monos):
            return
        events = self.session.device_events
        while self.events_delivered < len(events):
            r = events[self.events_delivered]
            a = self.session.anchor(r)
            here = (a.transitions, a.device_commands) == (len(self.transition_times), m)
            if not here or self.session.monotonic_of(r) >= monos[m]:
                return
            self.events_delivered += 1
            self.events.serve(self.session.device_event_payload(r))

    def _deliver_anchored_here(self, before_ns: int | None) -> None:
        events = self.session.device_events
        while self.replaying and self.events is not None and self.events_delivered < len(events):
            r = events[self.events_delivered]
            if before_ns is not None and r.t_ns >= before_ns:
                return
            a = self.session.anchor(r)
            if (a.transitions, a.device_commands) != (
                len(self.transition_times),
                len(self.device_command_times),
            ):
                return
            self.events_delivered += 1
            self.events.serve(self.session.device_event_payload(r))

    def moves(self) -> int:
        """How often the replay's job has moved on so far (transitions, device commands, the divergence);
        read from worker threads (the lists only grow, on the loop's thread)."""
        return len(self.transition_times) + len(self.device_command_times) + (self.divergence is not None)

    def at(self, anchor: Anchor) -> float | None:
        """The replay's monotonic time of ``anchor`` when its job has got there, else None."""
        n, m = anchor.transitions, anchor.device_commands
        if len(self.transition_times) < n or len(self.device_command_times) < m:
            return None
        base = max(
            self.transition_times[n - 1] if n else self._start_mono,
            self.device_command_times[m - 1] if m else self._start_mono,
        )
        return base + anchor.after_s

    async def reach(self, anchor: Anchor) -> bool:
        """Wait until the replay's job is where ``anchor`` says (then True), or no longer follows the
        recording (False)."""
        while self.replaying:
            t = self.at(anchor)
            if t is not None:
                await self.clock.sleep_until(t)
                return self.replaying
            if self._moved is None:
                self._moved = asyncio.Event()
            await self._moved.wait()
        return False

    def _read_time(self, r: Recorded, message: Message | UnsetType | None = UNSET) -> float:
        m = r.message if isinstance(message, UnsetType) else message
        t = m.t_read if isinstance(m, InputJoints | Force | Holding | ReadFailed) else UNSET
        if not isinstance(t, UnsetType):
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

    async def until_recorded(self, recorded: Recorded | Message | None) -> None:
        """Wait until the moment a recorded call ended, as the replay's clock lays it (``recorded``: its
        record, or the message decoded from it)."""
        end = _t_end(recorded)
        if end is not None and math.isfinite(end):
            await self.clock.sleep_until(self.replay_monotonic(end))

    # --- computing as long as the robot did --------------------------------------------------------------

    def computed_until(self, rec: Recorded) -> float | None:
        """When a computation served from ``rec`` (a motion plan, a placement plan) ends on the replay's
        clock: where the recorded one ended in the job (``RecordedSession.anchor``: after the same
        transitions and device commands, as long after the later of them), so that the daemon's other tasks
        (polls, health, telemetry, the recorded device events) run through that time as they did on the
        robot. A recorded end after something the replay's job has not done yet (a stop the daemon gave
        as it met a failure while the robot computed: the replay's will give it meanwhile) is laid on the
        replay's clock as the recording's clock is (lined up at the job's start). None when it ends now: in a
        simulated session computing took no simulated time (its replay stays exactly as it was), and a
        replay that is already past that point waits for nothing."""
        if self.session.simulated or not self.started:
            return None
        t = self.at(self.session.anchor(rec))
        if t is None:
            t = self.replay_monotonic(self.session.monotonic_of(rec))
        if t <= self.clock.monotonic() + _SAME_S:
            return None
        return t

    def compute_until(self, t: float) -> None:
        """From a worker thread computing for the job: take simulated time until ``t`` (the loop's tasks go
        on meanwhile); at once on the loop's own thread, which cannot wait for itself."""
        if isinstance(self.clock, SimulatedClock):
            self.clock.sleep_off_loop(t)

    def placement_until(self, rec: Recorded) -> float | None:
        """When a served placement plan (``rec``) is handed over: the recorded plan is the plan check's
        result, published when the check was done; the packing itself had ended before the first motion
        plan the check asked after it (the first one not served yet at the same place in the job)."""
        end = self.computed_until(rec)
        if end is None:
            return None
        here = self.session.anchor(rec)
        with self._motion_lock:
            items = self._ordered["motion"]
            for i in range(self._next["motion"], len(items)):
                r = items[i]
                if r.t_ns >= rec.t_ns:
                    break
                a = self.session.anchor(r)
                if i in self._motion_taken or (a.transitions, a.device_commands) != (
                    here.transitions,
                    here.device_commands,
                ):
                    continue
                t = self.at(a)
                if t is not None:
                    end = min(end, max(t, self.clock.monotonic()))
                break
        return end

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

    def has(self, stream: str) -> bool:
        """Whether the recording holds anything of ``stream`` (older ones lack some)."""
        items = self._timed.get(stream)
        return bool(items) if items is not None else bool(self._ordered.get(stream))

    def serving_events(self) -> bool:
        """Whether recorded device events stand in for the cell's (from before the job starts, as the
        recording holds none of the cell's before it either, until the replay stops following it)."""
        return self.replaying

    def failure(self, stream: str) -> Recorded | None:
        """The recorded failure of ``stream`` (``_FAILURES``) due now: the last of those not yet served
        recorded at or before this moment."""
        items = self._failures[stream]
        now = self.recorded_monotonic() + _SAME_S
        i = self._failures_next[stream]
        due: Recorded | None = None
        while i < len(items) and items[i][0] <= now:
            due = items[i][1]
            i += 1
        self._failures_next[stream] = i
        if due is not None:
            self.served[stream] = self.served.get(stream, 0) + 1
        return due

    def joints(self) -> Recorded | None:
        """The recorded joint sample the arm's reader now (``daemon.recorded.joint_reader``) gets: the job's
        next own read (by order); a telemetry poll's (any other reader's) by time among its own samples
        (``latest``). A recording that does not say who read (an older one): by time among them all. After
        the recorded job's last own read (a replay's job reading more than it did), by time among its own."""
        if self._joint_readers is None:
            return self.latest("input/joints")
        reader = current_joint_reader()
        if reader == JOB_READER and self._job_reads_next < len(self._job_reads):
            rec = self._job_reads[self._job_reads_next]
            self._job_reads_next += 1
            self.served["input/joints"] = self.served.get("input/joints", 0) + 1
            return rec
        stream = self._joint_readers.get(reader)
        return None if stream is None else self.latest(stream)  # (None: a reader the recording never saw)

    def latest(self, stream: str) -> Recorded | None:
        """The input of ``stream`` the daemon consumed at this moment: of those recorded at the same time,
        the next in the order they were consumed; else the last one recorded before."""
        i = self._latest_index(stream)
        return None if i is None else self._timed[stream][i]

    def holding(self) -> bool | None:
        """The holding flag the daemon read at this moment (``latest``); None before the first recorded."""
        i = self._latest_index("input/holding")
        return None if i is None else self._holding[i]

    def gripper(self) -> GripperState | None:
        """The gripper as the recorded telemetry last read it at or before this moment, its time the
        replay's (``RecordedSession.gripper``); None before the first read recorded. Not counted in
        ``served``: the telemetry's reads are no input of the job's."""
        telemetry = self.session.gripper
        i = bisect.bisect_right(telemetry.read_times, self.recorded_monotonic() + _SAME_S) - 1
        if i < 0:
            return None
        return GripperState(
            t=self.replay_monotonic(telemetry.read_times[i]),
            aperture_m=telemetry.aperture_m[i],
            load=telemetry.load[i],
        )

    def _latest_index(self, stream: str) -> int | None:
        times = self._timed_t[stream]
        now = self.recorded_monotonic()
        i = max(self._cursor.get(stream, 0), bisect.bisect_left(times, now - _SAME_S))
        if i < len(times) and abs(times[i] - now) <= _SAME_S:
            self._cursor[stream] = i + 1
        else:
            i = bisect.bisect_right(times, now) - 1
            if i < 0:
                return None
            last = self._last_served.get(stream, -1)
            if stream.startswith("input/joints") and not self.session.simulated:
                i = self._wall_joint_read(stream, i, last, now)
        self._last_served[stream] = max(i, self._last_served.get(stream, -1))
        served = stream.partition(":")[0]  # (one reader's joint samples count as joints)
        self.served[served] = self.served.get(served, 0) + 1
        return i

    def _wall_joint_read(self, stream: str, i: int, last: int, now: float) -> int:
        """The joint sample of a wall-clock recording a read at ``now`` (recorded monotonic) gets, ``i`` being
        the last one recorded at or before it and ``last`` the latest one served so far. On the wall clock
        each recorded read was one read, and the robot's job read no earlier than the replay's does (its
        computing and its bus took time): a sample read before now was another read's (a poll's), one
        served already too. So the next sample not served yet is the one the job read, when it comes within
        ``_WALL_READ_S``. A failed read is never taken early (it comes at its time); neither is a sample
        that is not served yet when its read failed. ``stream``: every sample (a recording that does not say
        who read), or one reader's."""
        times, ok = self._timed_t[stream], self._timed_ok[stream]
        j = max(i, last) + 1
        if j >= len(times) or times[j] - now > _WALL_READ_S:
            return i
        if i <= last:
            return j  # (the latest at or before now was served already: always the next one)
        return j if ok[i] and ok[j] else i

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

    def take_motion(self, call: str, digest: str, got: str) -> Recorded | None:
        """The recorded plan for a motion planner call: the first one not yet served that was asked with the
        same arguments, wherever it is in the recording (the job's plan check plans several cycles at once,
        so the calls are recorded in the order they finished; and a plan check served the recorded final
        plan asks only the calls of its last packing round: the recorded rounds before it are never asked
        again). Else the next one not yet served after the last one served, whose arguments then differ (a
        divergence for the caller to name)."""
        with self._motion_lock:
            chosen = self._choose_motion(call, digest)
            items = self._ordered["motion"]
            if chosen < len(items):
                self._motion_taken.add(chosen)
                self._motion_last = max(self._motion_last, chosen)
                while self._next["motion"] in self._motion_taken:
                    self._motion_taken.discard(self._next["motion"])
                    self._next["motion"] += 1
                self.served["motion"] = self.served.get("motion", 0) + 1
                return items[chosen]
        if self.session.cut is not None:
            self.recording_ended()
            return None
        # The recorded job asked no more plans: was it interrupted while this one was being made (a device
        # fault, a stop)? Then what interrupted it comes (a failed read, a device event, each at its time
        # while this thread waits on the simulated clock: as long as the recorded job took to move on from
        # here, and a while more), and the job moves on without this plan.
        since = self.moves()
        if self.session.simulated:  # computing took no simulated time: what came meanwhile comes first
            self.deliver_events_while_computing(None)
        if self.replaying and not self.made_every_transition():
            self.compute_until(self.interrupted_until())
        # (A job that made every recorded transition already, its final one, asks from a thread it left:
        # the plan check's next probe after the one refused.)
        if self.replaying and (self.moves() != since or self.made_every_transition()):
            raise MotionRefused(
                f"{call}: the recorded job was interrupted while this plan was being made (not recorded)"
            )
        self.diverge("motion", "nothing more recorded", got)
        return None

    def interrupted_until(self) -> float:
        """How long a computation the recorded job never finished (a fault, a stop interrupted it) waits for
        the replay's job to move on as the recorded one did: until as long after the recorded job moved on
        from where the replay's job is now, and ``_INTERRUPTED_WAIT_S`` more."""
        return max(self.clock.monotonic(), self._recorded_move_on()) + _INTERRUPTED_WAIT_S

    def made_every_transition(self) -> bool:
        """Whether the replay's job has made every transition the recorded job made (it ended as recorded,
        or is where the recording stops)."""
        return len(self.transition_times) >= len(self.session.transition_monos)

    def exhausted(self, stream: str) -> bool:
        """Whether every recorded result of ``stream`` (served by order) has been served."""
        return self._next[stream] >= len(self._ordered[stream])

    def _recorded_move_on(self) -> float:
        """When the recorded job moved on from where the replay's job is now (its next transition or device
        command), on the replay's clock; now when it never did."""
        n, m = len(self.transition_times), len(self.device_command_times)
        transitions, commands = self.session.transition_monos, self.session.device_command_monos
        later = [*transitions[n : n + 1], *commands[m : m + 1]]
        if not later:
            return self.clock.monotonic()
        start = self.session.start_monotonic
        base = max(transitions[n - 1] if n else start, commands[m - 1] if m else start)
        t = self.at(Anchor(n, m, max(0.0, min(later) - base)))
        return self.clock.monotonic() if t is None else t

    def _choose_motion(self, call: str, digest: str) -> int:
        """The index of the motion record to serve (``take_motion``), taken out of the index by arguments;
        the number of records when none is left. Under ``_motion_lock``."""
        items = self._ordered["motion"]
        same = self._motion_by_args.get((call, digest))
        if same:
            return same.popleft()
        chosen = max(self._next["motion"], self._motion_last + 1)
        while chosen in self._motion_taken:
            chosen += 1
        if chosen < len(items):
            p = _as(items[chosen], Motion)
            with contextlib.suppress(KeyError, ValueError):
                self._motion_by_args[(p.call, p.args_digest)].remove(chosen)
        return chosen

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
    """``backend`` (the simulated cell) with its devices, observer, health, device events, placement and
    motion planning behind ``replayer``."""
    hand_force_samples(backend, replayer)
    motion_for = backend.motion_for
    health: DeviceHealth | None = backend.health
    if health is not None or replayer.session.streams.get("input/health_failed"):
        health = ReplayHealth(health, replayer, replayer.session.config.hardware.health.poll_period_s)
    return replace(
        backend,
        arm=ReplayArm(backend.arm, replayer),
        gripper=ReplayGripper(backend.gripper, replayer),
        force=ReplayForce(backend.force, replayer),
        observer=ReplayObserver(backend.observer, replayer),
        placement=ReplayPlacement(replayer),
        motion=ReplayMotion(backend.motion, replayer),
        motion_for=None if motion_for is None else lambda tray: ReplayMotion(motion_for(tray), replayer),
        on_event=ReplayEvents(backend.on_event, replayer).register,
        health=health,
    )


def hand_force_samples(backend: Backend, replayer: Replayer) -> None:
    """While the replay follows a started job, the stand-in's FSR simulator hands each sample to its reader
    at its tick instead of sending the line (``FsrSimulator.tap_samples``): the job is served the recorded
    force, but the stand-in's own grasps close on its reader, the kinematic world is moved on at every
    tick by the force it is asked for, and after a divergence the reader must be where its stream would
    have left it (its median window, holding flag and debounce, sequence and counters). Only the bytes
    are skipped; the lines flow again from the divergence on (faults act after it)."""
    from daemon.sim_backend import KinematicCounter, MujocoCounter

    counter = backend.counter
    if not isinstance(counter, KinematicCounter | MujocoCounter):
        return
    reader = counter.cell.force

    def take(sample: Sample) -> bool:
        if not (replayer.replaying and replayer.started):
            return False
        reader.take_sample(sample)
        return True

    counter.cell.fsr_sim.tap_samples(take)


def _error_classes() -> dict[str, type[BaseException]]:
    found: dict[str, type[BaseException]] = {}
    for module_name in _ERROR_MODULES:
        with contextlib.suppress(ImportError):
            module = importlib.import_module(module_name)
            for value in vars(module).values():
                if isinstance(value, type) and issubclass(value, DriverError | BusLost | ValueError):
                    found.setdefault(f"{value.__module__}.{value.__qualname__}", value)
    return found


def recorded_failure(text: str, failure: Failure | None = None) -> BaseException:
    """The driver error a recorded failure names (``ServoFault: servo 3 overload``), raised again: of the
    class it had (``error_class``, else the first driver error of that name) with what it carried
    (``error_servo_id``, ``error_bits``, ``error_port``), else a ``DriverError`` of the same name."""
    name, _, message = text.partition(": ")
    failure = failure or Failure()
    classes = _error_classes()
    cls = classes.get(failure.error_class) if isinstance(failure.error_class, str) else None
    if cls is None:
        cls = next((c for c in classes.values() if c.__name__ == name), None)
    if cls is not None:
        error = cls.__new__(cls)
        Exception.__init__(error, message)
        servo_id, bits, port = failure.error_servo_id, failure.error_bits, failure.error_port
        attributes: dict[str, object] = {
            "servo_id": servo_id if isinstance(servo_id, int) else None,
            "bits": tuple(str(b) for b in bits) if isinstance(bits, list) else (),
            "port": port if isinstance(port, str) else "",
            "problems": (),
        }
        for key, value in attributes.items():
            with contextlib.suppress(AttributeError):
                if not hasattr(error, key):
                    setattr(error, key, value)
        return error
    stand_in: type[DriverError] = type(name, (DriverError,), {})
    return stand_in(message)


async def _bounded(call: Awaitable[T], replayer: Replayer, rec: Recorded | Message | None) -> T | None:
    """Run the cell's side of a served call only until the recorded call ended (then it is cancelled: the
    robot stopped there, or had done); its result when it ended first. ``rec``: the recorded call (its
    record, or the message decoded from it)."""
    task = asyncio.ensure_future(call)
    end = _t_end(rec)
    if end is None or not math.isfinite(end):
        return await task
    try:
        done = await replayer.clock.wait(
            task, max(0.0, replayer.replay_monotonic(float(end)) - replayer.clock.monotonic())
        )
    except asyncio.CancelledError:
        task.cancel()
        raise
    if done:  # (how the cell's side ended matters not: the recording says how the call did)
        return None if task.cancelled() or task.exception() is not None else task.result()
    task.cancel()
    await asyncio.wait({task})  # (a cancellation of this call itself still goes through)
    if not task.cancelled():
        task.exception()  # retrieved: the recording says how the call ended
    return None


async def _cell_side(call: Awaitable[T], replayer: Replayer, rec: Message | None) -> T | None:
    """The cell's side of a served move, opening or close: as the robot did, as far as it went (``_bounded``
    when the recorded call failed); in a stand-in for another cell only until the recorded call ended, as a
    cell slower than the robot (MuJoCo's arm for a kinematic or a robot's recording) must not make the job
    read the recording's later inputs while it still moves. Its result when it ran to its end."""
    if _failed(rec) or replayer.other_cell:
        return await _bounded(call, replayer, rec)
    return await call


async def _ended_as_recorded(replayer: Replayer, rec: Recorded, m: Message | None) -> None:
    """After a served call (``rec``, decoded ``m``): at its recorded end, fail as it failed; a call
    recorded as cancelled waits for the replay's job to cancel it too (divergence when it does not)."""
    await replayer.until_recorded(m)
    if _failed(m):  # what the drivers reported as the call failed comes before the job's reaction to it
        replayer.deliver_before_next_command()
    _raise_recorded(m)
    if _failure(m).cancelled is True:
        await replayer.clock.sleep(_CANCEL_WAIT_S)
        replayer.diverge("device", f"{rec.kind} cancelled", f"{rec.kind} not cancelled")


class ReplayArm:
    def __init__(self, inner: ArmDriver, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._inner.joint_names

    async def read_joints(self) -> JointState:
        rec = self._r.joints() if self._r.serving() else None
        if rec is None:  # (a read changes nothing in the cell: while served, the cell is not read)
            return await self._inner.read_joints()
        p = rec.message  # (decoded once)
        _raise_recorded(p)
        if not isinstance(p, InputJoints):
            raise ReplayError(f"{rec.kind}: recorded as {type(p).__name__}, not InputJoints")
        return JointState(
            t=self._r.clock.monotonic(),
            names=tuple(p.names),
            position_rad=_floats(p.position_rad),
            velocity_rad_s=_floats(p.velocity_rad_s),
            load=_floats(p.load),
        )

    async def follow(self, trajectory: JointTrajectory) -> None:
        asked = device_command(
            "output/follow",
            {"label": trajectory.label, "end_rad": [float(v) for v in trajectory.positions[-1]]}
            if len(trajectory.times)
            else {"label": trajectory.label, "end_rad": []},
            self._r.t_s(),
        )
        self._r.device_command()
        rec = self._r.take("follow", asked.describe() if asked else "") if self._r.serving() else None
        if rec is None or not self._r.check(rec, asked):
            await self._inner.follow(trajectory)
            return
        m = rec.message  # (decoded once for the call)
        await _cell_side(self._inner.follow(trajectory), self._r, m)
        await _ended_as_recorded(self._r, rec, m)

    async def stop(self) -> None:
        m = self._r.device_command()
        await self._inner.stop()
        await self._r.as_long_as_recorded(m)

    async def relax(self) -> None:
        self._r.device_command()
        await self._inner.relax()


class ReplayGripper:
    def __init__(self, inner: GripperDriver, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    async def read(self) -> GripperState:
        """The gripper as the recorded telemetry read it while the recording is served (a read that failed
        then fails now), the cell's after. Only the telemetry reads the gripper: the cell's is not read
        meanwhile (a read changes nothing in the cell), as the arm is not."""
        if self._r.serving():
            failure = self._r.failure("input/gripper_failed")
            if failure is not None:
                _raise_recorded(failure)
            recorded = self._r.gripper()
            if recorded is not None:
                return recorded
        return await self._inner.read()

    async def open(self, aperture_m: float | None = None) -> None:
        self._r.device_command()
        asked = device_command("output/gripper", {"action": "open", "aperture_m": aperture_m}, self._r.t_s())
        rec = self._r.take("open", asked.describe() if asked else "") if self._r.serving() else None
        if rec is None or not self._r.check(rec, asked):
            await self._inner.open(aperture_m)
            return
        m = rec.message  # (decoded once for the call)
        await _cell_side(self._inner.open(aperture_m), self._r, m)
        await _ended_as_recorded(self._r, rec, m)

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        self._r.device_command()
        asked = device_command("input/grasp", {"force_threshold_n": force_threshold_n}, self._r.t_s())
        rec = self._r.take("grasp", asked.describe() if asked else "") if self._r.serving() else None
        closing = self._inner.close_on_mug(force_threshold_n=force_threshold_n, min_aperture_m=min_aperture_m)
        if rec is None:
            return await closing
        p = rec.message  # (decoded once for the call)
        live = await _cell_side(closing, self._r, p)
        if not self._r.check(rec, asked):
            return (
                live
                if live is not None
                else await self._inner.close_on_mug(
                    force_threshold_n=force_threshold_n, min_aperture_m=min_aperture_m
                )
            )
        await _ended_as_recorded(self._r, rec, p)
        if not isinstance(p, Grasp):  # recorded as cancelled, and the replay's job was not: nothing held
            return GraspResult(held=False, force_n=0.0, aperture_m=0.0, reason="")
        return GraspResult(
            held=p.held,
            force_n=_float(p.force_n),
            aperture_m=_float(p.aperture_m),
            reason=p.reason if isinstance(p.reason, str) else "",
        )

    async def stop(self) -> None:
        m = self._r.device_command()
        await self._inner.stop()
        await self._r.as_long_as_recorded(m)


class ReplayForce:
    def __init__(self, inner: ForceSensor, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    def latest(self) -> ForceReading | None:
        rec = self._r.latest("input/force") if self._r.serving() else None
        if rec is None:
            return self._inner.latest()
        p = _as(rec, Force)
        device_t = p.t_device
        t = self._r.replay_monotonic(float(device_t)) if not isinstance(device_t, UnsetType) else 0.0
        return ForceReading(
            t=t,
            force_n=float(p.force_n),
            raw=p.raw if isinstance(p.raw, int) else 0,
            seq=p.seq if isinstance(p.seq, int) else 0,
        )

    def holding(self) -> bool:
        held = self._r.holding() if self._r.serving() else None
        return self._inner.holding() if held is None else held


class ReplayObserver:
    def __init__(self, inner: MugObserver, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer

    async def observe(self) -> Observation:
        self._r.device_command()
        rec = self._r.take("observation", "a look at the counter") if self._r.serving() else None
        looking = self._inner.observe()  # the cell's camera and detector run as they did
        if rec is None:
            return await looking
        p = rec.message  # (decoded once for the call)
        live = await _bounded(looking, self._r, p) if _failed(p) else await looking
        if not self._r.replaying:
            return live if live is not None else await self._inner.observe()
        await _ended_as_recorded(self._r, rec, p)
        if live is None:
            live = Observation(t=self._r.clock.monotonic(), detections=())
        if not isinstance(p, RecordedObservation):  # recorded as cancelled, and the replay's job was not
            return Observation(t=live.t, detections=(), depth_preview=live.depth_preview, meta={})
        device_t, meta = p.t_device, p.meta
        return Observation(
            t=self._r.replay_monotonic(float(device_t)) if not isinstance(device_t, UnsetType) else live.t,
            detections=tuple(_detection(d) for d in p.mugs),
            depth_preview=live.depth_preview,
            meta={str(k): str(v) for k, v in meta.items()} if not isinstance(meta, UnsetType) else {},
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
        if self._r.serving() and self._r.exhausted("plan") and self._r.session.cut is None:
            # The recorded job got no more plans: was it interrupted while it packed (a device fault, a
            # stop)? What interrupted it comes at its time while this waits, and the job moves on (this
            # call is cancelled with the job's state); else the replay diverges here.
            await self._r.clock.sleep_until(self._r.interrupted_until())
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
        until = self._r.placement_until(rec)  # as long as the robot's packing took
        if until is not None:
            await self._r.clock.sleep_until(until)
        return result


class ReplayHealth:
    """The devices' health as the recording has it: a poll that failed then fails now (the same error);
    the cell's own after divergence (or nothing, when the cell has no devices to poll)."""

    def __init__(self, inner: DeviceHealth | None, replayer: Replayer, poll_period_s: float) -> None:
        self._inner = inner
        self._r = replayer
        self._period = inner.poll_period_s if inner is not None else poll_period_s

    @property
    def poll_period_s(self) -> float:
        return self._period

    async def poll(self) -> None:
        if self._r.serving():
            failure = self._r.failure("input/health_failed")
            if failure is not None:
                _raise_recorded(failure)
            return
        if self._inner is not None:
            await self._inner.poll()

    def problems(self) -> tuple[str, ...]:
        return self._inner.problems() if self._inner is not None else ()

    async def clear(self) -> tuple[str, ...]:
        return await self._inner.clear() if self._inner is not None else ()


class ReplayEvents:
    """Device events (``Backend.on_event``): while the replay follows the recording, the recorded ones,
    handed to the daemon by ``replay.engine`` where they fell in the job (``Replayer.reach``), and none of
    the cell's; the cell's after divergence."""

    def __init__(self, inner: Callable[[EventListener], None] | None, replayer: Replayer) -> None:
        self._inner = inner
        self._r = replayer
        self.listeners: list[EventListener] = []
        replayer.events = self

    def register(self, listener: EventListener) -> None:
        self.listeners.append(listener)
        if self._inner is None:
            return

        def cells(event: Mapping[str, object]) -> None:  # possibly on a driver's thread
            if not self._r.serving_events():
                listener(event)

        self._inner(cells)

    def serve(self, payload: Mapping[str, object]) -> None:
        """Hand the daemon a recorded device event now (on the event loop)."""
        # A device event is an open document: its keys beyond the declared ones are the driver's own, and
        # the daemon's listeners take it as a table: it is handed on as recorded, its times the replay's.
        # (Read as the declared ``Event`` it could be refused for a driver's own key of a declared name, so
        # its device time is read from the table too; what its record added, ``t_read`` among it, is gone:
        # ``RecordedSession.device_event_payload``.)
        event = dict(payload)
        event["t"] = self._r.clock.now()
        device_t = payload.get("t_device")
        if isinstance(device_t, int | float) and not isinstance(device_t, bool):
            event["t_device"] = self._r.replay_monotonic(float(device_t))
        self._r.served["device_event"] = self._r.served.get("device_event", 0) + 1
        for listener in self.listeners:
            listener(event)


class ReplayMotion(MotionCalls):
    """Motion planning as the recording has it: the n-th recorded plan while the job asks for it with the
    same arguments (``wire.motion.args_digest``); else (divergence, and after it) the planner itself. A
    recording without plans (an older one) has the planner plan. Called from the job's worker threads."""

    def __init__(self, inner: MotionPlanner, replayer: Replayer) -> None:
        self.inner = inner
        self._r = replayer

    def _call(self, call: str, args: tuple[object, ...], run: Callable[[], T]) -> T:
        if not self._r.has("motion") or not self._r.serving():
            return run()
        digest = args_digest(call, *args)
        rec = self._r.take_motion(call, digest, f"{call} for the job's arguments")
        if rec is None:
            return run()
        p = _as(rec, Motion)
        if p.call != call or p.args_digest != digest:
            self._r.diverge("motion", f"{p.call} as recorded", f"{call} for other arguments")
            return run()
        # As long as the robot took to make it (the daemon's other tasks go on meanwhile), and what came
        # while it did comes before the job has it.
        until = self._r.computed_until(rec)
        if until is not None:
            self._r.compute_until(until)
        self._r.deliver_events_while_computing(rec.t_ns)
        if isinstance(p.refused, str):
            raise MotionRefused(p.refused, blockers=p.blockers if isinstance(p.blockers, list) else ())
        if isinstance(p.result, UnsetType):
            error = p.error if isinstance(p.error, str) else None
            self._r.diverge("motion", f"{call} failed ({error})", f"{call} planned again")
            return run()
        try:
            return cast("T", result_from_json(call, p.result))
        except (BadMotionRecord, ValueError) as e:
            self._r.diverge("motion", "a recorded plan", f"an unreadable one ({e})")
            return run()


def _on(loop: asyncio.AbstractEventLoop) -> bool:
    """Whether this thread runs ``loop``."""
    try:
        return asyncio.get_running_loop() is loop
    except RuntimeError:
        return False


M = TypeVar("M", bound=Message)

# The recorded calls that may have failed, and so carry the error fields (``wire.messages.Failure``).
_CALLS = (Follow, GripperCommand, Grasp, CallFailed, RecordedObservation, ReadFailed, InputJoints, Motion)


def _as(rec: Recorded, kind: type[M]) -> M:
    """A recorded input as its declared message (``RecordedSession.load`` checked it is one)."""
    m = rec.message
    if not isinstance(m, kind):
        raise ReplayError(f"{rec.kind}: recorded as {type(m).__name__}, not {kind.__name__}")
    return m


def _message(rec: Recorded | Message | None) -> Message | None:
    """A recorded call's message: decoded from its record, or as the caller decoded it already."""
    return rec.message if isinstance(rec, Recorded) else rec


def _failure(rec: Recorded | Message | None) -> Failure:
    """How a recorded call failed: its error fields and whether it was cancelled (none for a call that
    did not fail)."""
    return _failure_of(_message(rec))


def _failure_of(m: Message | None) -> Failure:
    """``_failure`` of a recorded call's decoded message."""
    if isinstance(m, Follow | GripperCommand | CallFailed):
        return Failure(
            error=m.error,
            error_class=m.error_class,
            error_servo_id=m.error_servo_id,
            error_bits=m.error_bits,
            error_port=m.error_port,
            cancelled=m.cancelled,
        )
    if isinstance(m, ReadFailed | Motion):
        return Failure(
            error=m.error,
            error_class=m.error_class,
            error_servo_id=m.error_servo_id,
            error_bits=m.error_bits,
            error_port=m.error_port,
        )
    return Failure()


def _t_end(rec: Recorded | Message | None) -> float | None:
    m = _message(rec)
    end = (
        m.t_end
        if isinstance(m, Follow | GripperCommand | Grasp | CallFailed | RecordedObservation)
        else UNSET
    )
    return None if isinstance(end, UnsetType) else float(end)


def _failed(rec: Recorded | Message | None) -> bool:
    return _failed_message(_message(rec))


def _failed_message(m: Message | None) -> bool:
    failure = _failure_of(m)
    return isinstance(failure.error, str) or failure.cancelled is True


def _raise_recorded(rec: Recorded | Message | None) -> None:
    failure = _failure_of(_message(rec))
    if isinstance(failure.error, str):
        raise recorded_failure(failure.error, failure)


def _floats(values: list[int | float] | UnsetType) -> tuple[float, ...]:
    return () if isinstance(values, UnsetType) else tuple(float(v) for v in values)


def _float(value: int | float | UnsetType) -> float:
    return 0.0 if isinstance(value, UnsetType) else float(value)


def _detection(d: RecordedDetection) -> Detection:
    return Detection(
        type=d.type,
        x_m=float(d.x_m),
        y_m=float(d.y_m),
        upside_down=d.upside_down is True,
        handle_yaw_rad=_float(d.handle_yaw_rad),
        confidence=_float(d.confidence),
        mug_id=d.id if isinstance(d.id, str) else "",
        handle_seen=d.handle_seen is not False,
    )
