"""The job runner: owns the chart and dispatches each leaf state to its unit of work, each command to
``commands`` and each device report to ``devices``.

One control task owns the chart. The unit of the current leaf (``registry.UNITS``) runs as a separate asyncio
task; when it ends it posts its outcome (an event with guard values) to the control task's inbox, and
commands arrive through the same inbox, so every transition is fired from one task, one at a time. That
matters because transitions' AsyncMachine cancels whatever a model's callbacks are still awaiting when
another transition starts: here the callbacks never await anything and the long work is never inside one.

Leaving a state whose work still runs (pause, stop, fault, estop) cancels that work and waits for it; units
leave the arm holding still when cancelled (``manipulation``). Work is resumable: the cycle's next step index
is kept in the context, and ``resume`` asks the next move to join the interrupted trajectory.

A job that can make no progress always ends in ``fault`` at its state's bound: whatever fails on the way
(a log line that cannot be written, a bug in handling one outcome) is reported and never keeps a unit's
outcome from reaching the control task, the deadline's fault from being sent, or the control task from
taking the next item.

Beside the dispatch, the runner only holds the parts together: the state bounds are ``deadlines``', the
recording's health ``recording_health``'s, what one job carries over to the next ``carry``'s.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
from collections.abc import Callable, Mapping

import structlog

from daemon.backend import Backend
from daemon.config import Config
from daemon.job.carry import carried, carry_over
from daemon.job.commands import Command, Commands
from daemon.job.context import JobContext, JobSummary, Outcome
from daemon.job.deadlines import Deadlines
from daemon.job.devices import DeviceSupervisor
from daemon.job.errors import CommandRefused
from daemon.job.recording_health import RecordingHealth, RecordingWatch
from daemon.job.registry import UNITS
from daemon.job.requests import PlannerRequest, StartRequest
from daemon.job.services import Publish, Services
from daemon.job.unit import Unit
from drivers.errors import BusLost, DriverError, LimitViolation
from perception.errors import CameraFault
from perception.interfaces import Associate
from planning.interfaces import MotionRefused
from statechart.chart import JOB_STATES, top_level
from statechart.errors import EventRefused
from statechart.machine import StateChart, Transition
from wire.messages import FaultEvent, State

log = structlog.get_logger("daemon.job")


class Job:
    """Runs loading jobs on a backend: owns the chart and dispatches each state's work, each command
    (``commands``) and each device's report (``devices``)."""

    def __init__(
        self,
        backend: Backend,
        config: Config,
        publish: Publish,
        associate: Associate,
        *,
        chart: StateChart | None = None,
        executor: concurrent.futures.Executor | None = None,
        recording: RecordingHealth | None = None,
    ) -> None:
        """``executor`` (a process pool) runs placement planning off this process, so its CPU time does not
        hold the GIL against the event loop; without it, planning runs in a thread. ``recording`` is the
        session's recording, whose health ``status`` reports and whose losses the summary counts."""
        self.backend = backend
        self.config = config
        self.chart = chart or StateChart()
        self._services = Services(
            backend, config, publish, associate, state=lambda: self.chart.state, executor=executor
        )
        self._devices = DeviceSupervisor(self._services, working=self._working, fault=self.fault)
        self._commands = Commands(self._services, self._devices, self)
        self._inbox: asyncio.Queue[Command | tuple[int, Outcome]] = asyncio.Queue()
        self._work: asyncio.Task[None] | None = None
        self._generation = 0
        self._ctx = JobContext(planner=PlannerRequest().options(config.planner))
        self._transitions = 0
        self._recording = RecordingWatch(self._services, recording)
        self._deadlines = Deadlines(self._services, config.daemon.state_bound_s, self.fault)
        self.finished = asyncio.Event()
        self.chart.subscribe(self._on_transition)

    # --- public surface ------------------------------------------------------------------------------------

    def carry_over(self, earlier: JobContext) -> None:
        """Take ``earlier`` as what the jobs before this daemon's first one left (the mugs on the tray, the
        counter it knew, the next mug id): a replay of a job that continued an earlier job's tray starts
        from it, as the recorded daemon did. Only while idle, before a job starts."""
        self._ctx = carry_over(self.chart.state, self._ctx, earlier)

    @property
    def summary(self) -> JobSummary:
        dropped = self._recording.dropped_since_start()
        if dropped is not None and self._ctx.summary.started_at is not None:
            self._ctx.summary.recording_dropped = dropped
        return self._ctx.summary

    def overdue(self) -> str | None:
        """Why the job is not making progress: its state has passed its time bound and the job has not left
        it yet (None: within its bound, or not working). The watchdog is not pinged meanwhile."""
        return self._deadlines.overdue()

    def recording(self) -> dict[str, object] | None:
        """The recording's health for ``status`` (None: this job records nothing)."""
        return self._recording.health()

    def recording_health(self, path: str, error: str | None) -> None:
        """Writing the recording failed (``error``) or works again (None), on the event loop: published on
        ``events`` (``recording_failed``, ``recording_restored``). The job carries on either way: a robot
        that loses its recording is still safe."""
        self._recording.report(path, error)

    def carried(self) -> dict[str, object]:
        """What a job started now without a new counter carries over from the jobs before it (the mugs on
        the tray as they were placed, the counter it knew, the next mug id), for its recording's header: a
        replay of it starts from exactly that (``carry_over``)."""
        return carried(self._ctx)

    def status(self) -> State:
        """The ``state`` message: where the chart is and how far the job got."""
        ctx = self._ctx
        return State(
            state=self.chart.state,
            mugs_total=len(ctx.counter) + len(ctx.on_tray),
            mugs_planned=ctx.summary.planned,
            mugs_placed=len(ctx.on_tray),
            mugs_failed=ctx.summary.failed,
            current_mug=ctx.current.mug_id if ctx.current else None,
            transitions=self._transitions,
            t=self._services.wall_time(),
        )

    async def command(self, verb: str, request: StartRequest | None = None) -> dict[str, object]:
        """Queue a command for the control task and wait for its reply; ``CommandRefused`` when refused."""
        return await self._submit(Command(verb, request, "", asyncio.get_running_loop().create_future()))

    async def fault(self, reason: str) -> None:
        """A device failed outside a state's work (e.g. while reading telemetry): enter fault."""
        with contextlib.suppress(CommandRefused):
            await self._submit(Command("fault", None, reason, asyncio.get_running_loop().create_future()))

    def device_event(self, event: Mapping[str, object]) -> None:
        """A driver's fault or recovery, on the event loop: published, and a fault when it stops the job
        (``DeviceSupervisor.on_event``)."""
        self._devices.on_event(event, self.chart.state)

    async def run(self) -> None:
        """The control task: fire each outcome or command in turn. Cancel it to stop (after ``shutdown``)."""
        while True:
            item = await self._inbox.get()
            try:
                await self._take(item)
            except Exception as e:  # a bug handling one item must not leave the job with no control task
                _say(log.error, "control_failed", error=repr(e))
                if isinstance(item, Command) and not item.reply.done():
                    item.reply.set_exception(CommandRefused(f"internal error: {e!r}"))
                await self._fault_after_failure(f"internal error: {e!r}")

    async def _take(self, item: Command | tuple[int, Outcome]) -> None:
        if isinstance(item, Command):
            await self._handle(item)
            return
        generation, outcome = item
        if generation != self._generation:
            return  # the state this work belonged to was left already
        await self._advance(outcome)

    async def _fault_after_failure(self, reason: str) -> None:
        """Enter fault after the control task failed to carry something out, unless the job is not working
        (or is in fault already); the transition's own failure is only reported."""
        if not self._working() or not self.chart.can("fault"):
            return
        try:
            await self._devices.safe_stop()
            self._services.event(FaultEvent(reason=reason))
            await self._fire(Outcome("fault", {"reason": reason}))
        except Exception as e:  # reported; the deadline or the operator may still end it
            _say(log.error, "control_failed", error=repr(e))

    async def shutdown(self) -> None:
        """Stop any motion safely (the process is exiting)."""
        self._deadlines.cancel()
        await self._cancel_work()
        await self._devices.stop_arm()

    # --- commands ------------------------------------------------------------------------------------------

    async def _submit(self, cmd: Command) -> dict[str, object]:
        await self._inbox.put(cmd)
        return await cmd.reply

    async def _handle(self, cmd: Command) -> None:
        try:
            result = await self._commands.execute(cmd)
        except CommandRefused as e:
            if not cmd.reply.done():
                cmd.reply.set_exception(e)
            return
        if not cmd.reply.done():
            cmd.reply.set_result(result)

    # --- what a command may ask (``commands.Control``) ------------------------------------------------------

    @property
    def context(self) -> JobContext:
        """The job's context (what its units share)."""
        return self._ctx

    def begin(self, ctx: JobContext) -> None:
        """A new job starts with ``ctx``, now: its summary's clock starts, the recording's losses are counted
        from here, and ``finished`` is cleared."""
        self._ctx = ctx
        self._ctx.summary.started_at = self._services.monotonic()
        self._ctx.summary.clock = self._services.clock
        self._recording.job_started()
        self.finished.clear()

    async def cancel_work(self) -> None:
        """Cancel the current state's work and wait for it (its outcome is then ignored)."""
        await self._cancel_work()

    async def fire(self, outcome: Outcome) -> None:
        """Fire ``outcome`` on the chart and start the new state's work."""
        await self._fire(outcome)

    async def advance(self, outcome: Outcome) -> None:
        """``fire``, stopping the arm and reporting the fault first when it is one."""
        await self._advance(outcome)

    # --- driving the chart ---------------------------------------------------------------------------------

    async def _advance(self, outcome: Outcome) -> None:
        if outcome.trigger == "fault":
            await self._devices.safe_stop()
            _say(log.error, "fault", reason=outcome.values.get("reason", ""))
            self._services.event(FaultEvent(reason=str(outcome.values.get("reason", ""))))
        await self._fire(outcome)

    async def _fire(self, outcome: Outcome) -> None:
        try:
            await self.chart.fire(outcome.trigger, **dict(outcome.values))
        except EventRefused as e:
            raise CommandRefused(str(e)) from e
        self._start_work()

    def _on_transition(self, change: Transition) -> None:
        self._transitions += 1
        detail = {k: v for k, v in change.detail.items() if isinstance(v, str | int | float | bool)}
        self._services.transition(trigger=change.trigger, source=change.source, dest=change.dest, **detail)
        self._services.publish("state", self.status())
        self._deadlines.entered(change.source, change.dest, plan_time_limit_s=self._ctx.planner.time_limit_s)
        if change.dest in ("done", "fault", "estop") or (change.dest == "idle" and change.trigger == "stop"):
            self._ctx.summary.ended_at = self._services.monotonic()
            self._ctx.summary.end_state = change.dest
            self.finished.set()

    def _working(self) -> bool:
        return top_level(self.chart.state) in JOB_STATES

    def _start_work(self) -> None:
        """Start the unit of the leaf the chart is in now (if it is one of the job's)."""
        self._generation += 1
        unit = UNITS.get(self.chart.state)
        if unit is None:
            return
        self._work = asyncio.create_task(self._run_work(unit, self._generation), name=f"work:{unit.leaf}")

    async def _run_work(self, unit: Unit, generation: int) -> None:
        bound = log.bind(state=unit.leaf, mug_id=self._ctx.current.mug_id if self._ctx.current else None)
        try:
            outcome = await unit.work(self._services, self._ctx)
        except asyncio.CancelledError:
            raise
        except CameraFault as e:  # its message names the camera and why: "camera: no frame within 2.0 s"
            _say(bound.error, "camera_failed", error=str(e))
            outcome = Outcome("fault", {"reason": str(e)})
        except (DriverError, BusLost, LimitViolation) as e:
            _say(bound.error, "device_failed", error=str(e))
            outcome = Outcome("fault", {"reason": f"{type(e).__name__}: {e}"})
        except MotionRefused as e:
            outcome = Outcome("fault", {"reason": f"motion refused: {e}"})
        except Exception as e:  # a bug must not leave the job hanging in a state with no work
            _say(bound.exception, "work_crashed")
            outcome = Outcome("fault", {"reason": f"internal error in {unit.leaf}: {e!r}"})
        self._inbox.put_nowait((generation, outcome))  # unbounded: never waits, never fails

    async def _cancel_work(self) -> None:
        self._generation += 1
        work, self._work = self._work, None
        if work is not None and not work.done():
            await cancel_and_wait(work)


async def cancel_and_wait(task: asyncio.Task[object] | asyncio.Task[None]) -> None:
    """Cancel ``task`` and wait until it has ended. Its cancellation is not an error here; the caller's own
    is, and goes on: a caller cancelled while it waits (the daemon stopping the control task as the control
    task stops a unit) must end too, not take its next item and wait for ever, the daemon's shutdown with
    it (``suppress(CancelledError)`` around the wait swallowed both)."""
    task.cancel()
    await wait_cancelled(task)


async def wait_cancelled(task: asyncio.Task[object] | asyncio.Task[None]) -> None:
    """Wait until ``task``, already cancelled, has ended: its cancellation is swallowed, the caller's own
    goes on (``cancel_and_wait``)."""
    try:
        await task
    except asyncio.CancelledError:
        current = asyncio.current_task()
        if current is not None and current.cancelling():
            raise


def _say(method: Callable[..., object], event: str, **fields: object) -> None:
    """Log where a failing log call must not change what the job does next (an outcome not posted, a fault
    not sent): the daemon's output is guarded already (``daemon.log_relay``), this holds for any logger."""
    with contextlib.suppress(Exception):
        method(event, **fields)
