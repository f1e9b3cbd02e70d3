"""The daemon process: one event loop running the job, the telemetry, the command server and the recording.

``serve`` opens the Zenoh session (and the live Foxglove server when asked), then the recording: a file per
job and rotating idle files (``recorder.files``), with the Foxglove channels derived from what is
recorded (``recorder.foxglove_scene``). It wires the backend's driver-boundary inputs into the recording,
publishes every log record on ``log`` (the planning worker's too, through ``daemon.log_relay``), starts the
job's control task and the telemetry loops (state, joints, gripper), answers commands, pings the systemd
watchdog from the loop, and on SIGTERM/SIGINT (or, with ``once``, when the job ends) stops motion, finishes
the recording and closes the session. A start that is refused (an endpoint or port in use, a directory that
cannot be written) leaves no recording file behind.

Shutdown runs every step even when one before it failed, each within its bound, and no thread of the
daemon's holds the process's exit, so SIGTERM ends it well within the unit's ``TimeoutStopSec`` with the
recording finished. A dead output (``| head``, a killed ``| tee``) changes nothing: the lines it cannot
take are dropped and counted (``RunResult.log_lines_lost``, the ``daemon_stopped`` record on ``log``).

Everything runs on the backend's clock: telemetry periods, the watchdog's, the ``t`` of every message and
the recording's log times (simulated time in simulation, the wall clock on the robot). On simulated time
the clock waits for the recorder's queue before it moves on, so nothing is dropped however loaded the
machine is (``SessionClock.add_backlog``).

It refuses to start on an endpoint other machines can reach without TLS unless told it is insecure on
purpose (then it warns at every start), and it says once when it loses its last peer or router and once when
one is back; Zenoh reconnects meanwhile, and nothing on the loop waits for the network.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import gc
import inspect
import os
import signal
from collections.abc import Awaitable, Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import structlog
import zenoh

from daemon import commands_handler
from daemon.backend import Backend
from daemon.clock import SessionClock, every_wall_period, wall_seconds
from daemon.config import Config
from daemon.errors import ConfigError, UsageError
from daemon.job import Job, JobSummary, StartRequest
from daemon.job.runner import wait_cancelled
from daemon.log_relay import LogRelay, LostLines, RecordQueue, output_guarded, plain_record
from daemon.messages import gripper_message, joints_message
from daemon.recorded import TELEMETRY_READER, JobPosition, joint_reader, recorded
from daemon.sdnotify import SdNotifier
from daemon.security import endpoint_protocol, exposure_error
from daemon.zenoh_session import ZenohSession, error_text
from drivers.dynamixel import BusTimeout
from drivers.dynamixel.health import ServoHealthFault
from drivers.errors import BusLost, DriverError, ServoFault
from perception.interfaces import Associate
from recorder.files import SessionRecording, is_job_file
from recorder.outcome import JobOutcome
from wire.messages import Command, ConnectionLostEvent, ConnectionRestoredEvent, Payload, plain

if TYPE_CHECKING:
    from recorder.foxglove_server import LiveServer

log = structlog.get_logger("daemon")

# How long a servo may report a fault to the telemetry before the job faults: longer than the gripper's own
# overload recovery (relax, restore the torque limit or reboot, retry: a few hundred milliseconds).
_SERVO_FAULT_GRACE_S = 1.0
# How long stopping the arm may take at shutdown before the daemon goes on closing everything else.
_SHUTDOWN_MOTION_S = 10.0
# With ``once``: how long a job may stay past its state's bound (the fault could not end the state: a stop
# that hangs) before the daemon gives up on it and exits, rather than run on with nothing left to do.
_STUCK_GRACE_S = 60.0


@dataclass(frozen=True, slots=True)
class RunOptions:
    """How ``dishbot run`` was asked to run."""

    listen: tuple[str, ...]
    connect: tuple[str, ...]
    record_dir: Path
    once: StartRequest | None = None  # run this one job at once, then exit
    foxglove: tuple[str, int] | None = None  # serve the live Foxglove view on this host and port
    worker_logs: RecordQueue | None = None  # the planning worker's log records, for the `log` topic
    insecure: bool = False  # plain endpoints beyond loopback allowed for this run (--insecure)


@dataclass(frozen=True, slots=True)
class ServeContext:
    """What a running daemon is made of, for the hooks that act on it from outside the job (a replay's
    scripted commands and injected faults): all of it lives on the clock's event loop."""

    config: Config
    backend: Backend  # as the job sees it (recorded: every input also goes to the recording)
    job: Job
    session: ZenohSession
    recording: SessionRecording
    stop: asyncio.Event
    clock: SessionClock
    handle: Callable[[str, bytes, bool], Awaitable[dict[str, object]]]  # a command, as if it came by Zenoh


@dataclass(frozen=True, slots=True)
class ServeHooks:
    """Ways in for a replay or a fault plan, without reaching into the job: ``on_publish`` sees every
    message the daemon publishes (on the loop, in order; it must not block), ``on_ready`` is called once
    the daemon is ready, before the ``once`` job starts."""

    on_publish: tuple[Callable[[str, Mapping[str, object]], None], ...] = ()
    on_ready: Callable[[ServeContext], None] | None = None


@dataclass(frozen=True, slots=True)
class RunResult:
    summary: JobSummary
    recording: Path  # the last job's file (the last file when no job ran)
    end_state: str
    outcome: JobOutcome = field(default_factory=JobOutcome)
    files: tuple[Path, ...] = ()  # every recording file written
    wall_s: float = 0.0  # how long the ``once`` job took on this machine (its duration is on the clock)
    simulated: bool = False
    log_lines_lost: int = 0  # log lines the process's output could not take (a closed pipe)


def job_header(request: StartRequest, config: Config) -> dict[str, object]:
    """What a job runs, for its recording's header: the dataset or mugs asked for, the effective planner
    settings (the configured ones with the request's overrides, as the job applies them) and the seeds."""
    r = request.planner
    effective = r.options(config.planner)  # as the job applies them
    asked = {
        k: v
        for k, v in (
            ("method", r.method),
            ("cost", r.cost),
            ("fitness", r.fitness),
            ("time_limit_s", r.time_limit_s),
            ("seed", r.seed),
        )
        if v is not None
    }
    mugs = None
    if request.mugs is not None:
        mugs = [{"id": m.mug_id, "type": m.type, "x_m": m.x_m, "y_m": m.y_m} for m in request.mugs]
    return {
        "dataset": request.dataset,
        "mugs": mugs,
        "planner": {
            "method": effective.method,
            "cost": effective.cost,
            "fitness": effective.fitness,
            "time_limit_s": effective.time_limit_s,
            "seed": effective.seed,
        },
        "planner_overrides": asked,
        "sim_seed": config.sim.seed if config.backend == "sim" else None,
    }


def tolerated_exposure(config: Config, options: RunOptions) -> str | None:
    """How the endpoints expose the arm to other machines without TLS, when ``insecure`` allows it (to be
    warned about); raises ``UsageError`` naming the fix when it does not. None: nothing is exposed."""
    try:
        exposed = exposure_error(options.listen, options.connect, config.zenoh)
    except ConfigError as e:
        raise UsageError(str(e)) from e
    if exposed is not None and not (options.insecure or config.zenoh.insecure):
        raise UsageError(exposed)
    return exposed


def listen_in_use(listen: Sequence[str]) -> str | None:
    """Why one of the ``tcp/`` or ``tls/`` endpoints to listen on is already taken (another daemon on this
    machine, most often: the default port is the same for every job), or None. Checked before any device
    or simulator starts, so a second ``dishbot run`` on one machine turns no servo's torque on before it
    fails; the Zenoh session, opened later, still reports whatever else goes wrong."""
    import errno
    import socket

    for endpoint in listen:
        if endpoint_protocol(endpoint) not in ("tcp", "tls"):
            continue
        address = endpoint.split("/", 1)[1].split("?", 1)[0].split("#", 1)[0]
        host, _, port = address.rpartition(":")
        host = host[1:-1] if host.startswith("[") else host
        if not port.isdigit() or int(port) == 0:
            continue
        try:
            family, kind, proto, _, where = socket.getaddrinfo(
                host or None, int(port), type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
            )[0]
        except OSError:
            continue  # a host that does not resolve: the session's own error says so
        with socket.socket(family, kind, proto) as probe:
            # As a listener binds: a port left in TIME_WAIT by an earlier run is free, one listened on is not.
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind(where)
            except OSError as e:
                if e.errno != errno.EADDRINUSE:
                    continue
                return (
                    f"cannot listen on {endpoint}: the address is in use (another dishbot running on this "
                    "machine? give this one a free port with --listen tcp/127.0.0.1:PORT)"
                )
    return None


async def serve(
    config: Config,
    backend: Backend,
    associate: Associate,
    options: RunOptions,
    *,
    notifier: SdNotifier,
    on_ready: Callable[[ZenohSession, Path], None] | None = None,
    stop: asyncio.Event | None = None,
    executor: concurrent.futures.Executor | None = None,
    hooks: ServeHooks | None = None,
) -> RunResult:
    """Run the daemon until SIGTERM/SIGINT or ``stop`` is set (or the ``once`` job ends); returns the last
    job's summary."""
    exposed = tolerated_exposure(config, options)
    if exposed is not None:
        log.warning("zenoh_insecure", problem=exposed)
    try:
        options.record_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"cannot create the recording directory {options.record_dir}: {e.strerror}") from e
    if not os.access(options.record_dir, os.W_OK | os.X_OK):
        raise UsageError(f"cannot write recordings to {options.record_dir}: permission denied")
    try:
        session = ZenohSession.open(
            config.robot_id,
            listen=options.listen,
            connect=options.connect,
            max_command_bytes=config.daemon.max_command_bytes,
            zenoh_config=config.zenoh,
        )
    except zenoh.ZError as e:
        raise UsageError(
            f"cannot open the Zenoh session (listen {list(options.listen)}): {error_text(e)}"
        ) from e
    clock = backend.clock
    live: LiveServer | None = None
    try:
        view = None
        if config.foxglove.channels:
            from daemon.hardware import scene_view
            from recorder.foxglove_arm import UrdfError

            try:
                view = scene_view(config, depth_hz=config.foxglove.depth_hz)
            except UrdfError as e:
                raise UsageError(str(e)) from e
        if options.foxglove is not None:
            from recorder.errors import LiveServerError
            from recorder.foxglove_server import LiveServer, known_channels

            try:
                live = LiveServer(
                    *options.foxglove,
                    name=f"dishbot {config.robot_id}",
                    channels=known_channels(config.robot_id, scene=view is not None),
                )
            except LiveServerError as e:
                raise UsageError(str(e)) from e
    except BaseException:
        if live is not None:
            live.close()
        session.close()
        raise
    recording = SessionRecording(
        config.recording,
        options.record_dir,
        config.robot_id,
        config=config.to_dict(),
        scene=backend.scene,
        clock=clock.describe(),
        job=job_header(options.once, config) if options.once is not None else None,
        deriver=view,
        tee=live,
        lossless=clock.simulated,
    )
    relay = (
        LogRelay(options.worker_logs, _publish_log(session, clock))
        if options.worker_logs is not None
        else None
    )
    caught_up = clock.add_backlog(recording.caught_up)
    try:
        with output_guarded() as lost, _logs_published(session, clock):
            session.attach_recorder(recording, lambda: round(clock.now() * 1e9))
            await asyncio.to_thread(recording.apply_retention)
            return await _run(
                config,
                backend,
                associate,
                options,
                notifier,
                session,
                recording,
                on_ready,
                stop or asyncio.Event(),
                executor,
                live,
                relay,
                hooks or ServeHooks(),
                lost,
            )
    finally:
        caught_up()
        if live is not None:
            live.close()


async def _run(
    config: Config,
    backend: Backend,
    associate: Associate,
    options: RunOptions,
    notifier: SdNotifier,
    session: ZenohSession,
    recording: SessionRecording,
    on_ready: Callable[[ZenohSession, Path], None] | None,
    stop: asyncio.Event,
    executor: concurrent.futures.Executor | None,
    live: LiveServer | None,
    relay: LogRelay | None,
    hooks: ServeHooks,
    lost: LostLines,
) -> RunResult:
    loop = asyncio.get_running_loop()
    clock = backend.clock
    # Every read at the driver boundary (the telemetry's too) is recorded as an input for replay.
    position = JobPosition()  # where the job is when a command or a device event comes (for replay)
    backend = recorded(backend, session.record, position)
    outcome = JobOutcome()

    def publish(topic: str, payload: Payload) -> None:
        if topic == "events":
            outcome.add(payload)  # what `--once` says about each mug
            position.saw(topic, payload)
        session.publish(topic, payload)
        if hooks.on_publish:
            seen = plain(payload)  # the taps (a replay's, a fault plan's) read the JSON object
            for tap in hooks.on_publish:
                tap(topic, seen)

    job = Job(backend, config, publish, associate, executor=executor, recording=recording)

    def recording_health(path: Path, error: str | None) -> None:  # from the recorder's thread
        with contextlib.suppress(RuntimeError):  # the loop is closed: the daemon is gone
            loop.call_soon_threadsafe(job.recording_health, str(path), error)

    recording.on_health(recording_health)

    async def handle(verb: str, payload: bytes, many: bool) -> dict[str, object]:
        if verb == "start" and not many:  # what the job will run goes into its file's header
            with contextlib.suppress(commands_handler.BadCommand):
                request = commands_handler.parse(verb, payload, config)
                if request is not None:
                    header = job_header(request, config)
                    if request.dataset is None and request.mugs is None:  # the tray goes on: say how
                        header["carried"] = job.carried()
                    recording.expect_job(header)
        # The operator's commands are inputs too: a replay sends them again where they came in the job
        # (``position``, taken as the command arrives) (``status`` asks and changes nothing: not kept).
        t, t_device = clock.now(), clock.monotonic()
        at = position.state, position.transitions, position.device_commands
        reply = await commands_handler.handle(job, verb, payload, many)
        if verb != "status":
            text = payload.decode("utf-8", "replace")
            session.record(
                "input/command",
                Command(
                    t=t,
                    t_device=t_device,
                    verb=verb,
                    payload=text,
                    many=many,
                    reply=reply,
                    at_state=at[0],
                    at_transitions=at[1],
                    at_device_commands=at[2],
                ),
            )
        return reply

    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    tasks = [
        asyncio.create_task(job.run(), name="job"),
        asyncio.create_task(
            _every(clock, 1.0 / config.daemon.state_rate_hz, lambda: _state(session, job)), name="state"
        ),
        asyncio.create_task(_joints_loop(session, backend, job, config.daemon.joints_rate_hz), name="joints"),
        asyncio.create_task(
            _gripper_loop(session, backend, job, config.daemon.gripper_rate_hz), name="gripper"
        ),
        asyncio.create_task(_health_loop(backend, job), name="health"),
    ]
    health = ConnectionHealth(session, job, clock)
    path = options.record_dir
    wall_s = 0.0
    try:
        # Inside the try from here on: whatever fails (a hook that refuses, a fault the cell cannot have, a
        # notify socket gone) still stops everything cleanly.
        if notifier.watchdog_interval_s is not None:
            # systemd watches the wall clock. A simulated clock paced to it (``--speed``, as a service runs
            # the simulated cell) pings on the wall clock too: its time stands still while a plan is
            # computed, which can take longer than the watchdog allows. As fast as the machine allows, the
            # pings follow simulated time (what the stall tests read).
            interval = notifier.watchdog_interval_s / 2.0
            paced = clock.simulated and getattr(clock, "speed", None) is not None
            pings = (
                every_wall_period(interval, _ping(notifier, job))
                if paced
                else _every(clock, interval, _ping(notifier, job))
            )
            tasks.append(asyncio.create_task(pings, name="watchdog"))
        if backend.on_event is not None:
            # Device events (driver faults, tray collisions) may come from other threads: the job handles them
            # on the loop, publishes them on `events` and faults when the device can no longer be trusted.
            def device_event(event: Mapping[str, object]) -> None:
                loop.call_soon_threadsafe(job.device_event, event)

            backend.on_event(device_event)
        session.serve(loop, handle, verbs=commands_handler.VERBS)
        if live is not None:  # the same verbs, answered by the same handler, for Foxglove's service panel
            live.offer_commands(
                loop,
                handle,
                config.robot_id,
                commands_handler.VERBS,
                max_payload_bytes=config.daemon.max_command_bytes,
            )
        if options.connect:  # the peers and routers it relies on; clients come and go
            session.watch_connections(loop, health.changed)
        session.publish("state", job.status())  # the first message: it opens the first recording file
        path = recording.path or options.record_dir
        # Everything allocated so far lives as long as the process: keep it out of the cyclic collector's
        # scans, whose full passes over it stalled the loop for tens of milliseconds. Once per process: a
        # process that serves again (tests, bench, replays) froze its long-lived part already, and freezing
        # again would keep each earlier serve's cyclic garbage from the collector for good.
        if gc.get_freeze_count() == 0:
            gc.collect()
            gc.freeze()
        notifier.ready(f"robot {config.robot_id} idle")
        log.info(
            "daemon_ready",
            robot_id=config.robot_id,
            listen=list(options.listen),
            recording=str(path),
            foxglove=live.url if live is not None else None,
        )
        if on_ready is not None:
            on_ready(session, path)
        if hooks.on_ready is not None:
            hooks.on_ready(ServeContext(config, backend, job, session, recording, stop, clock, handle))
        if options.once is not None:
            started = wall_seconds()
            await job.command("start", options.once)
            waits = {
                asyncio.create_task(job.finished.wait()),
                asyncio.create_task(stop.wait()),
                asyncio.create_task(_stuck(job, clock)),
            }
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
            for waiting in waits:
                waiting.cancel()
            wall_s = wall_seconds() - started
        else:
            await stop.wait()
    finally:

        async def stop_motion() -> None:
            async with clock.timeout(_SHUTDOWN_MOTION_S):
                await job.shutdown()

        async def stop_tasks() -> None:
            for task in tasks:
                task.cancel()
            for task in tasks:
                await wait_cancelled(task)  # not suppress(): that would swallow this task's own cancel too

        def remove_signal_handlers() -> None:
            for sig in (signal.SIGTERM, signal.SIGINT):
                loop.remove_signal_handler(sig)

        async def close_relay() -> None:
            if relay is not None:
                await asyncio.to_thread(relay.close)

        def said_goodbye() -> None:
            log.info("daemon_stopped", log_lines_lost=lost.count)  # on `log`, so in the recording

        await _each_step(
            [
                ("notify", lambda: notifier.stopping("stopping motion and finishing the recording")),
                ("log", lambda: log.info("daemon_stopping")),
                ("stop motion", stop_motion),
                ("state", lambda: session.publish("state", job.status())),
                ("tasks", stop_tasks),
                ("signals", remove_signal_handlers),
                ("log relay", close_relay),
                ("connections", health.close),
                ("goodbye", said_goodbye),
                ("detach recording", lambda: session.attach_recorder(None)),
                ("recording health", lambda: recording.on_health(_unheard)),  # nothing to publish it on
                ("zenoh", session.close),
                ("recording", lambda: asyncio.to_thread(recording.close)),
                ("backend", backend.close),
            ]
        )
    files = recording.files()
    jobs = [p for p in files if is_job_file(p)]
    last = jobs[-1] if jobs else (files[-1] if files else path)
    return RunResult(
        job.summary,
        last,
        job.chart.state,
        outcome,
        files,
        wall_s=wall_s,
        simulated=clock.simulated,
        log_lines_lost=lost.count,
    )


def _unheard(path: Path, error: str | None) -> None:
    """The recording's health once the session is closing: ``status`` still says it, nobody is told."""


async def _each_step(steps: Sequence[tuple[str, Callable[[], object]]]) -> None:
    """Run every step of the shutdown in turn (awaiting what it returns, when awaitable), even when a step
    before it failed: a failure is logged and the next step runs (the recording is finished, the session
    closed, whatever went wrong before)."""
    for name, step in steps:
        try:
            result = step()
            if inspect.isawaitable(result):
                await result
        except Exception as e:  # each step on its own: the next one runs whatever happened
            with contextlib.suppress(Exception):
                log.error("shutdown_step_failed", step=name, error=repr(e))


async def _stuck(job: Job, clock: SessionClock, *, grace_s: float = _STUCK_GRACE_S) -> None:
    """Return once the job has stayed past its state's bound for ``grace_s`` (the fault could not end the
    state); logged once. Checked every second of the clock."""
    overdue_since: float | None = None
    while True:
        now = clock.monotonic()
        reason = job.overdue()
        if reason is None:
            overdue_since = None
        elif overdue_since is None:
            overdue_since = now
        elif now - overdue_since >= grace_s:
            log.error("job_stuck", reason=reason, past_bound_s=round(now - overdue_since, 3))
            return
        await clock.sleep(1.0)


class ConnectionHealth:
    """Says once when the last peer or router goes away and once when one is back (log and ``events``).

    Zenoh keeps reconnecting to the ``connect`` endpoints with backoff; this only reports, and only a change
    that lasts ``settle_s`` (links flap while they are set up). Reaching none of them at start is said too."""

    def __init__(
        self, session: ZenohSession, job: Job, clock: SessionClock, *, settle_s: float = 1.0
    ) -> None:
        self._session = session
        self._job = job
        self._clock = clock
        self._settle_s = settle_s
        self._reported = True  # as if connected: only a lasting absence is news
        self._counts = (0, 0)
        self._timer: asyncio.TimerHandle | None = None
        self._closed = False

    def changed(self, peers: int, routers: int) -> None:
        """A transport opened or closed (on the loop): check again once things have settled."""
        if self._closed:
            return
        self._counts = (peers, routers)
        if self._timer is not None:
            self._timer.cancel()
        self._timer = asyncio.get_running_loop().call_later(self._settle_s, self._settled)

    def close(self) -> None:
        """Report nothing more (the session is closing: its links go down on purpose)."""
        self._closed = True
        if self._timer is not None:
            self._timer.cancel()

    def _settled(self) -> None:
        peers, routers = self._counts
        connected = peers + routers > 0
        if connected == self._reported:
            return
        self._reported = connected
        kind = "connection_restored" if connected else "connection_lost"
        if connected:
            log.info(kind, peers=peers, routers=routers)
        else:
            log.warning(kind, peers=peers, routers=routers)
        made = ConnectionRestoredEvent if connected else ConnectionLostEvent
        event = made(state=self._job.chart.state, t=self._clock.now(), peers=peers, routers=routers)
        self._session.publish("events", event)


def _state(session: ZenohSession, job: Job) -> None:
    session.publish("state", job.status())


def _ping(notifier: SdNotifier, job: Job) -> Callable[[], None]:
    """The watchdog ping: sent while the loop runs and the job makes progress (``Job.overdue``); a state past
    its bound stops it until the job has left the state (faulted), so a stall the fault cannot end gets the
    daemon restarted. The status line says why meanwhile."""
    stalled: str | None = None

    def ping() -> None:
        nonlocal stalled
        overdue = job.overdue()
        if overdue is None:
            notifier.watchdog()
        elif overdue != stalled:
            notifier.status(f"stalled: {overdue}")
        stalled = overdue

    return ping


async def _every(clock: SessionClock, period_s: float, action: Callable[[], None]) -> None:
    """Run ``action`` every ``period_s`` on ``clock``, without drifting."""
    next_t = clock.monotonic()
    while True:
        action()
        next_t += period_s
        await clock.sleep_until(next_t)


async def _polled(
    clock: SessionClock,
    period_s: float,
    read: Callable[[], Awaitable[None]],
    job: Job,
    what: str,
    *,
    servo_fault_grace_s: float = _SERVO_FAULT_GRACE_S,
) -> None:
    """Call ``read`` every ``period_s``; a device failure faults the job once and is logged once, then
    reading resumes quietly until it works again (logged once more).

    A lost bus, a servo that no longer answers (or only garbled) and a servo past a health limit fault at
    once. A servo reporting a fault (overload, say) faults only when it still does after
    ``servo_fault_grace_s``: the gripper driver clears an overload itself and retries the grasp, and the
    telemetry must not cut that recovery short."""
    next_t = clock.monotonic()
    failing = False
    servo_fault_since: float | None = None
    while True:
        try:
            await read()
            servo_fault_since = None
            if failing:
                log.info("telemetry_recovered", source=what)
                failing = False
        except (DriverError, BusLost) as e:
            now = clock.monotonic()
            recoverable = isinstance(e, ServoFault) and not isinstance(e, BusTimeout | ServoHealthFault)
            if recoverable and servo_fault_since is None:
                servo_fault_since = now
            persistent = not recoverable or (
                servo_fault_since is not None and now - servo_fault_since >= servo_fault_grace_s
            )
            if persistent and not failing:
                failing = True
                log.error("telemetry_failed", source=what, error=str(e))
                asyncio.get_running_loop().create_task(job.fault(f"{type(e).__name__}: {e}"))
        next_t += period_s
        await clock.sleep_until(next_t)


async def _health_loop(backend: Backend, job: Job) -> None:
    """Poll the devices' health (servo voltage and temperature) on the backend's clock: a servo past a
    limit faults the job at once, like a lost bus (none to poll: nothing to do)."""
    health = backend.health
    if health is None:
        return
    await _polled(backend.clock, health.poll_period_s, health.poll, job, "health")


async def _joints_loop(session: ZenohSession, backend: Backend, job: Job, rate_hz: float) -> None:
    clock = backend.clock

    async def read() -> None:
        with joint_reader(TELEMETRY_READER):  # (recorded as the telemetry's read, not the job's)
            js = await backend.arm.read_joints()
        session.publish("joints", joints_message(js, t=clock.now()))

    await _polled(clock, 1.0 / rate_hz, read, job, "joints")


async def _gripper_loop(session: ZenohSession, backend: Backend, job: Job, rate_hz: float) -> None:
    clock = backend.clock

    async def read() -> None:
        gs = await backend.gripper.read()
        reading = backend.force.latest()
        t = clock.now()
        session.publish("gripper", gripper_message(gs, reading, holding=backend.force.holding(), t=t))

    await _polled(clock, 1.0 / rate_hz, read, job, "gripper")


class _LogForwarder:
    """A structlog processor publishing every record on ``log`` (and so recording it), with ``t`` on the
    session's clock (structlog's own ``timestamp``, when configured, stays the process's wall clock)."""

    def __init__(self, session: ZenohSession, clock: SessionClock) -> None:
        self.session = session
        self.clock = clock

    def __call__(self, logger: object, method: str, event: Mapping[str, object]) -> Mapping[str, object]:
        with contextlib.suppress(Exception):  # logging must never take the daemon down
            record = plain_record(event, method)
            record.setdefault("t", self.clock.now())
            self.session.publish("log", record)
        return event


def _publish_log(session: ZenohSession, clock: SessionClock) -> Callable[[Mapping[str, object]], None]:
    """Publishes a relayed worker record with ``t`` on the session's clock (when it reached the daemon)."""

    def publish(record: Mapping[str, object]) -> None:
        session.publish("log", {**record, "t": record.get("t", clock.now())})

    return publish


@contextlib.contextmanager
def _logs_published(session: ZenohSession, clock: SessionClock) -> Iterator[None]:
    """While active, structlog records are also published on ``log`` (before the final renderer)."""
    before = list(structlog.get_config()["processors"])
    structlog.configure(processors=[*before[:-1], _LogForwarder(session, clock), *before[-1:]])
    try:
        yield
    finally:
        structlog.configure(processors=before)
