"""``replay``: one recorded job run again through the daemon, on simulated time, and compared.

The session header rebuilds the config and the simulated cell (the same world, dataset and seeds, the
simulated clock from the same wall-clock start); the daemon itself runs unchanged (``daemon.app.serve``:
the job, the statechart, the planners, the telemetry, the recorder, Zenoh with ``listen``). Its devices are
the replay's (``replay.drivers``): the recorded inputs for as long as the daemon does what it did,
the simulated cell after. The operator's recorded commands are sent again where they fell in the job (at
their times after a divergence). Faults (``replay.faults``) act on the simulated cell; the first one to fire
ends replaying, as any divergence does.

The replay's trace is what its daemon publishes and records, taken as it happens (a tee on the session),
not read back from the replay's own recording (kept only when asked, ``record``; a full disk cuts it); it
is compared with the recorded one: the states entered, the events, the device commands
(``replay.session.compare``).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import structlog

from daemon.app import RunOptions, ServeContext, ServeHooks, serve
from daemon.backend import SimOptions
from daemon.cell import open_backend
from daemon.clock import SessionClock, SimulatedClock, wall_seconds
from daemon.config import Config
from daemon.errors import UsageError
from daemon.sdnotify import SdNotifier
from daemon.security import ZenohConfig
from recorder.files import is_job_file
from recorder.reader import RecordedMessage
from replay.drivers import Replayer, replay_backend
from replay.errors import ReplayError
from replay.faults import FaultOutcome
from replay.resim import STAND_INS, Resimulated, Resimulation, carried_over, continues_earlier_job
from replay.session import (
    SIM_BACKENDS,
    Divergence,
    Recorded,
    RecordedSession,
    Trace,
    compare,
    trace_of_messages,
    traced_topic,
)
from validation import toml
from wire.messages import (
    UNSET,
    BadMessage,
    Command,
    Event,
    HeaderClock,
    HeaderJob,
    HeaderScene,
    Payload,
    Reply,
    UnsetType,
    convert,
    header_part,
    plain,
    reply_of,
)

log = structlog.get_logger("replay")

# How far past a cut recording's end the replay goes on before it stops (simulated s).
_PAST_CUT_S = 1.0
# The kinematic stand-in's joint speed cap for a robot's recording (the highest ``sim.joint_speed_rad_s``).
_STAND_IN_JOINT_SPEED_RAD_S = 10.0
# A recorded job that began longer than this after its daemon started is started at once in the replay
# rather than after as long an idle spell.
_MAX_IDLE_WAIT_S = 3600.0


class FaultSource(Protocol):
    """What the replay needs of a fault plan (``replay.faults.FaultInjector``)."""

    on_fire: Callable[[Any], None] | None

    def prepare(self, options: RunOptions) -> RunOptions: ...

    def attach(self, ctx: ServeContext) -> None: ...

    def on_publish(self, topic: str, payload: Mapping[str, object]) -> None: ...

    def close(self) -> None: ...

    @property
    def fired(self) -> Sequence[Mapping[str, object]]: ...

    def outcomes(self) -> tuple[FaultOutcome, ...]: ...

    @property
    def acts_on_recording(self) -> bool:
        """Whether a fault acts on the recording (a full disk), so the replay must write one."""
        ...


@dataclass(frozen=True, slots=True)
class ReplayOptions:
    speed: float | None = None  # simulated seconds per wall second; None: as fast as the machine allows
    record: Path | None = None  # keep the replay's recording here
    listen: tuple[str, ...] = ()  # Zenoh endpoints to publish on while replaying
    insecure: bool = False  # plain endpoints beyond loopback allowed (as ``dishbot run --insecure``)
    # The stand-in world after a divergence (``replay.resim``): kinematic or mujoco; None: the recording's
    # own simulated world, the kinematic one for a hardware recording.
    resim: str | None = None
    # How long a replay may run on after the recorded job's duration before it is given up (simulated s):
    # a job that never ends (a resume the recording lost) idles that long; a test of the limit takes less.
    overrun_s: float = 600.0


@dataclass(frozen=True, slots=True)
class ReplayReport:
    """What a replay did, against what was recorded."""

    session: Path
    recorded: Trace
    replayed: Trace
    first_divergence: Divergence | None
    faults: tuple[Mapping[str, object], ...]
    recorded_duration_s: float
    replay_duration_s: float  # simulated
    wall_s: float
    cut: str | None  # why the recording ends early, when it does
    recording: Path | None  # the replay's own recording, when kept
    served: Mapping[str, int] = field(default_factory=dict)
    world: str = ""
    fault_outcomes: tuple[FaultOutcome, ...] = ()  # every fault of the file: fired or not, and why not
    resim: Resimulated | None = None  # the stand-in cell, and from when the job went on in it

    @property
    def resimulated_from_s(self) -> float | None:
        """From when (seconds from the job's start) the world was re-simulated: model-based from there."""
        return None if self.resim is None else self.resim.from_s

    overran_s: float | None = None  # the limit (s from the job's start) the replay ran past, its job unended

    @property
    def unfired(self) -> tuple[FaultOutcome, ...]:
        """The faults of the file that did not happen (a replay that tested less than it says)."""
        return tuple(o for o in self.fault_outcomes if not o.fired)

    @property
    def match(self) -> bool:
        """The replay did what the recording says, up to its end (a recording cut short: up to the cut)."""
        return self.first_divergence is None

    def to_json(self) -> dict[str, object]:
        return {
            "session": str(self.session),
            "world": self.world,
            "match": self.match,
            "first_divergence": None if self.first_divergence is None else self.first_divergence.to_json(),
            "final_state": self.replayed.final_state,
            "recorded_final_state": self.recorded.final_state,
            "states": list(self.replayed.states),
            "recorded_states": list(self.recorded.states),
            "events": [e.to_json() for e in self.replayed.events],
            "faults": [dict(f) for f in self.faults],
            "fault_outcomes": [o.to_json() for o in self.fault_outcomes],
            "unfired": len(self.unfired),
            "recorded_duration_s": round(self.recorded_duration_s, 6),
            "replay_duration_s": round(self.replay_duration_s, 6),
            "wall_s": round(self.wall_s, 3),
            "speedup": round(self.replay_duration_s / self.wall_s, 2) if self.wall_s > 0 else None,
            "cut": self.cut,
            "recording": None if self.recording is None else str(self.recording),
            "served": dict(self.served),
            "stand_in": None if self.resim is None else self.resim.world,
            "resimulated_from_s": (
                None if self.resimulated_from_s is None else round(self.resimulated_from_s, 6)
            ),
            "resim": None if self.resim is None else self.resim.to_json(),
            "overran_s": self.overran_s,
        }

    def lines(self) -> list[str]:
        """The report as a person reads it."""
        out = [f"replayed {self.session.name} ({self.world}, recorded {self.recorded_duration_s:.1f} s)"]
        if self.cut is not None:
            out.append(f"the recording ends early at {self.recorded.duration_s:.1f} s: {self.cut}")
        if self.first_divergence is None:
            out.append(
                f"trace matched: {len(self.replayed.states)} states, {len(self.replayed.events)} events"
            )
        else:
            out.append(f"trace {self.first_divergence.line()}")
        if self.resim is not None:
            out.extend(self.resim.lines())
        for f in self.faults:  # (a fired fault's record is open: its target keys are its kind's own)
            target = f" servo {f['servo']}" if f.get("servo") is not None else ""
            out.append(f"fault fired: {f.get('kind')}{target} at {float(f.get('fired_at_s', 0.0)):.3f} s")  # type: ignore[arg-type]
        out.extend(o.line() for o in self.unfired)
        if self.overran_s is not None:
            out.append(
                f"the replay ran past its limit ({self.overran_s:.1f} s from the job's start) with the job "
                f"still in {self.replayed.final_state}, and was stopped"
            )
        out.append(f"final state {self.replayed.final_state} (recorded: {self.recorded.final_state})")
        counts: dict[str, int] = {}
        for e in self.replayed.events:
            counts[e.kind] = counts.get(e.kind, 0) + 1
        out.append("events " + ", ".join(f"{k} {n}" for k, n in sorted(counts.items())))
        ratio = f"{self.replay_duration_s / self.wall_s:.1f}x" if self.wall_s > 0 else "-"
        out.append(f"replayed {self.replay_duration_s:.1f} s in {self.wall_s:.1f} s wall ({ratio} real time)")
        if self.recording is not None:
            out.append(f"recording {self.recording}")
        return out


def replay(
    session: RecordedSession, options: ReplayOptions = ReplayOptions(), *, faults: FaultSource | None = None
) -> ReplayReport:
    """Replay ``session`` (blocking: it runs its own simulated event loop)."""
    if options.record is not None:
        check_record_path(options.record)
    stand_in_world(session, options.resim)  # a bad --resim before anything runs
    sweep_stale_replay_dirs()
    wall_start = _wall_start(session)
    clock = SimulatedClock(speed=options.speed, wall_start=wall_start)
    started = wall_seconds()
    tee = _Tee(forward=options.record is not None or (faults is not None and faults.acts_on_recording))
    with _terminated_as_exit(), tempfile.TemporaryDirectory(prefix=f"{_TMP_PREFIX}{os.getpid()}-") as tmp:
        replayer, resim, result_files = clock.run(_replay(session, options, clock, Path(tmp), faults, tee))
        wall_s = wall_seconds() - started
        # The trace is what the daemon published and recorded as it went, not what its recording kept
        # (a full disk, a dropped message must not change the report).
        replayed = trace_of_messages(tee.messages)
        if not replayed.states:
            raise ReplayError(
                f"{session.path}: the replay started no job (the daemon refused the start, or was stopped "
                "before it)"
            )
        kept: Path | None = None
        if options.record is not None:
            jobs = [p for p in result_files if is_job_file(p)]
            if jobs:
                options.record.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(jobs[0], options.record)
                kept = options.record
    recorded = session.trace
    divergence = replayer.divergence
    compared = compare(recorded, replayed, prefix=session.cut is not None)
    if compared is not None and (divergence is None or compared.t_s < divergence.t_s):
        divergence = compared
    return ReplayReport(
        session=session.path,
        recorded=recorded,
        replayed=replayed,
        first_divergence=divergence,
        faults=tuple(faults.fired) if faults is not None else (),
        fault_outcomes=faults.outcomes() if faults is not None else (),
        recorded_duration_s=recorded.duration_s,
        replay_duration_s=replayed.duration_s,
        wall_s=wall_s,
        cut=session.cut,
        recording=kept,
        served=dict(replayer.served),
        world=session.world,
        resim=resim.result,
        overran_s=replayer.overran_s,
    )


_TMP_PREFIX = "dishbot-replay-"


def check_record_path(path: Path) -> None:
    """``--record PATH`` can be written: a new file in a directory that exists (or can be made) and is
    writable; ``ReplayError`` (one line) before anything runs otherwise."""
    if path.exists() or path.is_symlink():
        raise ReplayError(f"--record {path}: the file exists; choose a new name")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ReplayError(f"--record {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ReplayError(f"--record {path}: cannot write in {parent} (permission denied)")


def sweep_stale_replay_dirs(base: Path | None = None) -> None:
    """Remove the working directories of replays whose process is gone (killed: nothing ran their
    clean-up); a replay's directory is named after its process id."""
    base = base if base is not None else Path(tempfile.gettempdir())
    for d in base.glob(f"{_TMP_PREFIX}*-*"):
        pid_text = d.name.removeprefix(_TMP_PREFIX).split("-", 1)[0]
        if not pid_text.isdigit() or not d.is_dir() or _alive(int(pid_text)):
            continue
        shutil.rmtree(d, ignore_errors=True)


@contextlib.contextmanager
def _terminated_as_exit() -> Iterator[None]:
    """SIGTERM ends the replay as an exception does, so that its working directory is removed (while the
    daemon runs, its own handler stops it in order instead)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    received: list[int] = []

    def terminated(signum: int, _frame: object) -> None:
        received.append(signum)
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, terminated)
    try:
        yield
    except Exception as e:
        # Raised where the signal landed, the exit can come out as another error (an import it interrupted
        # fails with ImportError): it is still the termination.
        if received:
            raise SystemExit(128 + received[0]) from e
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's
    return True


class _Tee:
    """The messages the daemon hands its recorder that make a trace (``traced_topic``: events, state and
    device commands), with the log time it stamped, as they happen: the replay's trace. Taken
    before the recorder's queue and disk, so a dropped or unwritten message is still in the trace.

    Not ``forward``ed, nothing reaches the recorder: a replay whose recording nobody keeps and no fault
    acts on (a full disk acts on the recorder; no other fault kind touches it) does not write one;
    encoding, deriving Foxglove's views of and compressing what would be thrown away was a sixth of a
    kinematic replay's time."""

    def __init__(self, *, forward: bool = True) -> None:
        self.messages: list[RecordedMessage] = []
        self._forward = forward

    def install(self, ctx: ServeContext) -> None:
        recording = ctx.recording
        write = recording.write

        forward = self._forward

        def tee(topic: str, payload: Payload, *, log_time_ns: int, data: bytes | None = None) -> bool:
            if traced_topic(topic):  # the trace's topics only: a long replay's memory stays flat
                self.messages.append(RecordedMessage(topic, log_time_ns, dict(plain(payload))))
            return write(topic, payload, log_time_ns=log_time_ns, data=data) if forward else True

        recording.write = tee  # type: ignore[method-assign]


def _wall_start(session: RecordedSession) -> float:
    """The replay's clock starts where the recording's did: the simulated clock's wall start, or the
    recording's first message on the wall clock."""
    start = header_part(session.clock, HeaderClock).wall_start
    if session.simulated and not isinstance(start, UnsetType):
        return float(start)
    return (session.read.start_ns or session.start_ns) / 1e9


def replay_config(session: RecordedSession, options: ReplayOptions, record_dir: Path) -> Config:
    """The recorded config, with what belongs to the machine it ran on taken out: the recording goes to
    the replay's directory, Zenoh has no peers to reach and no credentials of the robot's. A recording
    nobody keeps (no ``record``: one written only for a fault to act on) is written plain, without
    Foxglove's derived views."""
    config = session.config
    zenoh = ZenohConfig(listen=options.listen, connect=(), insecure=options.insecure)
    recording = dataclasses.replace(config.recording, dir=record_dir, max_total_mb=0, max_age_days=0)
    foxglove = config.foxglove
    if options.record is None:
        recording = dataclasses.replace(recording, compression=None)
        foxglove = dataclasses.replace(foxglove, channels=False)
    return dataclasses.replace(config, zenoh=zenoh, recording=recording, foxglove=foxglove)


async def _replay(
    session: RecordedSession,
    options: ReplayOptions,
    clock: SimulatedClock,
    record_dir: Path,
    faults: FaultSource | None,
    tee: _Tee,
) -> tuple[Replayer, Resimulation, tuple[Path, ...]]:
    config = replay_config(session, options, record_dir)
    stand_in = stand_in_world(session, options.resim)
    # A simulated recording's scene (its dataset or mugs, its seed) builds the stand-in; then it is only a
    # cross-check of what the recording saw. A hardware recording's stand-in is set from the recording.
    # A job that continued an earlier one's tray starts from what that job left, as the recording has it
    # (``replay.resim.carried_over``); its stand-in, too, is set from the recording.
    continued = continues_earlier_job(session)
    from_header = session.backend in SIM_BACKENDS and not continued
    if stand_in != session.world:
        # A stand-in for another cell (the robot's) must keep up with what that cell did while the recording
        # is served (its devices are driven too): the trajectories' own timing rules, not the kinematic
        # cell's speed cap.
        config = dataclasses.replace(
            config, sim=dataclasses.replace(config.sim, joint_speed_rad_s=_STAND_IN_JOINT_SPEED_RAD_S)
        )
    job = header_part(session.job, HeaderJob)
    dataset = header_part(session.scene, HeaderScene).dataset if job.mugs in (None, UNSET) else None
    seed = job.sim_seed
    try:
        backend = await open_backend(
            config,
            sim=SimOptions(
                world=stand_in,
                dataset=dataset if isinstance(dataset, int) and from_header else 1,
                transport="inprocess",
                seed=seed if isinstance(seed, int) else None,
            ),
            clock=clock,
            check_reach=False,  # (the recorded daemon checked this cell when it started)
        )
    except UsageError as e:
        raise ReplayError(f"{session.path}: the {stand_in} stand-in cannot be built: {e}") from e
    resim = Resimulation(session, backend, world=stand_in, from_header=from_header)
    replayer = Replayer(session, clock, on_diverge=lambda d: resim.take_over(d.t_s))
    replayer.other_cell = stand_in != session.world
    backend = replay_backend(backend, replayer)
    recorded_states = session.trace.states
    entered = 0

    def on_publish(topic: str, payload: Mapping[str, object]) -> None:
        nonlocal entered
        if topic != "events":
            return
        try:
            event = convert(payload, Event, name=topic)
        except BadMessage:  # not an event as declared: nothing of it in the trace either (``trace_of``)
            return
        kind = event.kind
        if kind == "transition":
            dest = "" if isinstance(event.dest, UnsetType) else event.dest
            if not replayer.started and event.trigger == "start":
                replayer.job_started()
                resim.job_started()
            if replayer.started:
                if replayer.replaying:
                    if entered >= len(recorded_states):
                        if session.cut is None:
                            replayer.diverge("state", f"stay in {session.trace.final_state}", f"enter {dest}")
                    elif recorded_states[entered] != dest:
                        replayer.diverge("state", f"enter {recorded_states[entered]}", f"enter {dest}")
                entered += 1
            replayer.state = dest
        elif kind == "fault_injected" and replayer.started:
            replayer.diverge(
                "fault", "no fault", "a fault" if isinstance(event.fault, UnsetType) else event.fault
            )

    stop = asyncio.Event()
    drive: list[asyncio.Task[None]] = []
    if faults is not None:

        def fired(spec: Any) -> None:  # just before the fault acts: the simulated cell takes over
            replayer.diverge("fault", "no fault", f"{spec.kind} {spec.trigger}")

        faults.on_fire = fired

    def on_ready(ctx: ServeContext) -> None:
        if continued:
            ctx.job.carry_over(carried_over(session))
        tee.install(ctx)
        if faults is not None:
            faults.attach(ctx)
        drive.append(asyncio.create_task(_drive(session, replayer, ctx, options.overrun_s), name="replay"))

    hooks = ServeHooks(
        on_publish=(on_publish,) if faults is None else (on_publish, faults.on_publish), on_ready=on_ready
    )
    run_options = RunOptions(
        listen=options.listen, connect=(), record_dir=record_dir, insecure=options.insecure
    )
    if faults is not None:
        run_options = faults.prepare(run_options)
    from perception import associate

    try:
        result = await serve(
            config, backend, associate, run_options, notifier=SdNotifier(None), stop=stop, hooks=hooks
        )
    finally:
        for task in drive:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if faults is not None:
            faults.close()
    return replayer, resim, result.files


def stand_in_world(session: RecordedSession, asked: str | None) -> str:
    """The world a replay re-simulates in: the one asked for, else the recording's own simulated world, else
    (a hardware recording) the kinematic one."""
    if asked is not None:
        if asked not in STAND_INS:
            raise ReplayError(f"--resim {asked}: choose {' or '.join(STAND_INS)}")
        return asked
    return session.world if session.world in STAND_INS else "kinematic"


async def _drive(session: RecordedSession, replayer: Replayer, ctx: ServeContext, overrun_s: float) -> None:
    """The operator's side: the recorded start, the later commands where they fell in the job (at the
    same transition and device command, as long after them: ``RecordedSession.anchor``) and the recorded
    device events likewise (a task of their own); once the replay no longer follows the recording, the
    commands at their times from the job's start. Then, once the job has ended and its file's tail is
    recorded, the end of the daemon; a job still going at the limit is reported (``overran_s``)."""
    clock = ctx.clock
    if session.simulated:
        # Start when the recorded daemon did (the same simulated time after the start of its clock): the
        # simulated cell then is exactly as it was.
        start_at = session.start_monotonic
        if 0.0 < start_at - clock.monotonic() <= _MAX_IDLE_WAIT_S:
            await clock.sleep_until(start_at)
    reply = reply_of(await ctx.handle("start", session.start_payload(), False))
    if reply.ok is not True:
        log.error("replay_start_refused", error=None if isinstance(reply.error, UnsetType) else reply.error)
        ctx.stop.set()
        return
    events = asyncio.create_task(_serve_device_events(session, replayer), name="replay-device-events")
    try:
        for command in session.later_commands():
            came = command.message
            if not isinstance(came, Command):  # (``RecordedSession.load`` decoded every input/command)
                raise ReplayError(f"{command.kind}: recorded as {type(came).__name__}, not Command")
            verb = came.verb
            await _when_it_came(session, replayer, clock, command, verb)
            reply = reply_of(await ctx.handle(verb, came.payload.encode(), came.many is True))
            recorded = None if isinstance(came.reply, UnsetType) else reply_of(came.reply)
            if recorded is not None and (recorded.ok is True) != (reply.ok is True):
                replayer.diverge(
                    "command", f"{verb} answered {_answer(recorded)}", f"{verb} answered {_answer(reply)}"
                )
        if session.cut is not None or not _finished(session.trace):
            # The recorded daemon ended at the cut, or was stopped with its job unfinished: so does the
            # replay (if the job is not over before), a moment after it, so that what happened at the very
            # instant of the end is in the replay too (only the recording's part is compared).
            left = max(0.0, session.end_s - replayer.t_s()) + _PAST_CUT_S
            await clock.wait(asyncio.ensure_future(ctx.job.finished.wait()), left)
        else:
            limit = session.trace.duration_s + overrun_s
            left = max(0.0, limit - replayer.t_s())
            finished = await clock.wait(asyncio.ensure_future(ctx.job.finished.wait()), left)
            if not finished:
                replayer.overran_s = limit
                log.error("replay_overran", limit_s=limit, state=replayer.state)
            await clock.sleep(_tail_s(session, replayer, ctx.config.recording.job_tail_s))
    finally:
        events.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await events
    ctx.stop.set()


def _tail_s(session: RecordedSession, replayer: Replayer, job_tail_s: float) -> float:
    """How long the replay's daemon goes on after its job ended. While the replay follows the recording, as
    long as the recording goes on after the recorded job's end (a job file ends ``job_tail_s`` after it, or
    as soon as its daemon stopped: a ``run --once`` job's about 40 ms after), and ``_TAIL_MARGIN_S`` more
    for what came at its very last instant: the trace is compared over what the recording holds, and past
    its end the recorded daemon did nothing to compare with (a short job faulted at once replayed its 2 s
    tail for nothing, most of its replay). A replay that went on in the re-simulated world (a divergence, a
    fault) goes on as the daemon does, ``job_tail_s``."""
    if not replayer.replaying:
        return job_tail_s
    recorded = max(0.0, session.end_s - session.trace.duration_s)
    return min(job_tail_s, recorded + _TAIL_MARGIN_S)


# What a faithful replay's daemon goes on for past the recording's last instant after its job (simulated s).
_TAIL_MARGIN_S = 0.01

# How far past the recorded time of an operator's command the replay's job may be before the command is
# sent anyway, as a divergence (simulated s): the job never got to where the command came.
_ANCHOR_SLACK_S = 30.0


async def _when_it_came(
    session: RecordedSession, replayer: Replayer, clock: SessionClock, command: Recorded, verb: str
) -> None:
    """Wait until the replay's job is where the recorded job was when ``command`` came; when the replay
    does not follow the recording (any more), until as long after the job's start as it came."""
    offset_s = session.monotonic_of(command) - session.start_monotonic
    if replayer.replaying:
        anchor = session.anchor(command)
        reaching = asyncio.ensure_future(replayer.reach(anchor))
        if await clock.wait(reaching, max(0.0, offset_s - replayer.t_s()) + _ANCHOR_SLACK_S):
            if reaching.result():
                return
        else:
            reaching.cancel()
            await asyncio.wait({reaching})
            replayer.diverge("command", f"{verb} {anchor.describe()}", f"{verb} in {replayer.state}")
    await clock.sleep_until(clock.monotonic() + max(0.0, offset_s - replayer.t_s()))


async def _serve_device_events(session: RecordedSession, replayer: Replayer) -> None:
    """Hand the daemon each recorded device event where it fell in the job, while the replay follows the
    recording (the cell's own events after)."""
    events = replayer.events
    if events is None:
        return
    for i, r in enumerate(session.device_events):
        if i < replayer.events_delivered:
            continue  # handed over while the job computed (``Replayer.deliver_events_while_computing``)
        if not await replayer.reach(session.anchor(r)):
            return
        if i < replayer.events_delivered:
            continue
        replayer.events_delivered = i + 1
        events.serve(session.device_event_payload(r))


def _finished(trace: Trace) -> bool:
    """Whether a recorded job ended (done, fault, estop, or stopped to idle), rather than its daemon
    stopping with the job still going."""
    if trace.final_state in ("done", "fault", "estop"):
        return True
    return trace.final_state == "idle" and len(trace.states) > 1


def _answer(reply: Reply) -> str:
    error = "" if isinstance(reply.error, UnsetType) else reply.error
    return "ok" if reply.ok is True else f"refused ({error})"


def load_and_replay(path: Path, options: ReplayOptions = ReplayOptions()) -> ReplayReport:
    """``RecordedSession.load`` then ``replay``: one call for scripts."""
    return replay(RecordedSession.load(path), options)


Faults = str | Path | Sequence[Mapping[str, object]]


def fault_text(faults: Faults) -> str:
    """TOML text for ``faults``: a file's text, the text itself, or ``[[fault]]`` tables of scalars."""
    if isinstance(faults, Path):
        return faults.read_text(encoding="utf-8")
    if isinstance(faults, str):
        return faults
    return toml.dumps({"fault": [dict(table) for table in faults]}) if faults else ""


__all__ = [
    "FaultSource",
    "Faults",
    "ReplayOptions",
    "ReplayReport",
    "fault_text",
    "load_and_replay",
    "replay",
]
