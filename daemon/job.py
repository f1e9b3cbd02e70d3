"""The job runner: does each state's work and drives the statechart with the outcomes.

One control task owns the chart. Work for the current leaf state runs as a separate asyncio task; when it ends
it posts an outcome (an event with guard values) to the control task's inbox, and commands arrive through the
same inbox, so every transition is fired from one task, one at a time. That matters because transitions'
AsyncMachine cancels whatever a model's callbacks are still awaiting when another transition starts: here the
callbacks never await anything and the long work is never inside one.

Leaving a state whose work still runs (pause, stop, fault, estop) cancels that work and waits for it; every
motion runs inside ``try/finally`` that stops the arm (and the gripper), so a cancelled state always leaves
the arm holding still. Work is resumable: the cycle's next step index is kept, and a move interrupted half
way is resumed by joining the interrupted trajectory at its nearest sample and following the rest.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, TypeVar

import numpy as np
import structlog

from daemon.backend import (
    Backend,
    CounterMug,
    CyclePlannerSpec,
    SlotPlanner,
    depth_preview_payload,
    observation_payload,
    plan_placement,
)
from daemon.config import Config
from drivers.errors import BusLost, DriverError, LimitViolation
from drivers.interfaces import Clock, JointTrajectory
from perception.interfaces import Detection
from planning.interfaces import CyclePlan, MotionRefused, MugPose, Step, StepKind, TraySlot
from planning.placement import CounterMug as PlanMug
from planning.placement import InvalidProblem, PlanOptions, Problem, TrayMug
from planning.placement import MugType as PlanMugType
from statechart.chart import CARRYING, CYCLE_PHASES, top_level
from statechart.errors import EventRefused
from statechart.machine import StateChart, Transition

log = structlog.get_logger("daemon.job")

Publish = Callable[[str, Mapping[str, object]], None]


class Associate(Protocol):
    """Lost-mug association (``perception.associate``): the seen detections, each with the id of the known
    mug it is ("" when new). ``target_id`` names the mug the arm was handling (it may have moved)."""

    def __call__(
        self, known: Sequence[Detection], seen: Sequence[Detection], *, target_id: str = ""
    ) -> Sequence[Detection]: ...


# The states of the loading job that do work (and may move the arm).
_WORKING = ("detect", "plan", "side_grasp", "flip", "place", "recover_lost_mug")

# How long the force sensor may be lost or silent while the job works before it faults (see device_event).
_FORCE_GRACE_S = 0.3

# After a pause, a move is joined at its nearest sample; within this of it, without a bridging move.
_ON_PATH_RAD = 0.02
# A held grasp is confirmed by the FSR reader's debounced ``holding()``, which turns true only after the force
# has stayed above its threshold for the debounce time (30 ms by default) and a sample has arrived after it.
# The verify waits for that, polling, for at most this long: several debounce windows and sample periods.
_GRASP_CONFIRM_S = 0.3
_GRASP_POLL_S = 0.005

T = TypeVar("T")


class CommandRefused(ValueError):
    """A command that is not allowed now or carries bad values; nothing changed."""


@dataclass(frozen=True, slots=True)
class PlannerRequest:
    """Planner preferences a ``start`` command may set (None keeps the configured value)."""

    method: str | None = None
    cost: str | None = None
    fitness: str | None = None
    time_limit_s: float | None = None
    seed: int | None = None


@dataclass(frozen=True, slots=True)
class StartRequest:
    """A validated ``start`` command body."""

    dataset: int | None = None
    mugs: tuple[CounterMug, ...] | None = None
    planner: PlannerRequest = PlannerRequest()


@dataclass(frozen=True, slots=True)
class Outcome:
    """What a state's work ended with: the event to fire and its guard values and detail."""

    trigger: str
    values: Mapping[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class JobSummary:
    """The numbers ``dishbot run --once`` prints and ``status`` reports."""

    detected: int = 0
    planned: int = 0
    placed: int = 0
    failed: int = 0
    grasp_failures: int = 0
    drops: int = 0
    started_at: float | None = None
    ended_at: float | None = None
    end_state: str = ""
    clock: Clock | None = field(default=None, repr=False, compare=False)  # what started_at is on

    @property
    def duration_s(self) -> float:
        """How long the job took (so far) on the backend's clock: simulated seconds in simulation."""
        if self.started_at is None:
            return 0.0
        end = self.ended_at
        if end is None:
            end = self.clock.monotonic() if self.clock is not None else self.started_at
        return end - self.started_at

    def to_json(self) -> dict[str, object]:
        return {
            "detected": self.detected,
            "planned": self.planned,
            "placed": self.placed,
            "failed": self.failed,
            "grasp_failures": self.grasp_failures,
            "drops": self.drops,
            "duration_s": round(self.duration_s, 3),
            "end_state": self.end_state,
        }


@dataclass(slots=True)
class _Context:
    """Everything one loading job knows."""

    planner: PlanOptions
    counter: dict[str, MugPose] = field(default_factory=dict)
    given_up: set[str] = field(default_factory=set)
    attempts: dict[str, int] = field(default_factory=dict)
    on_tray: list[TraySlot] = field(default_factory=list)
    tray_mugs: list[TrayMug] = field(default_factory=list)
    queue: list[tuple[TraySlot, TrayMug]] = field(default_factory=list)
    needs_plan: bool = True
    current: TraySlot | None = None
    current_tray_mug: TrayMug | None = None
    cycle: CyclePlan | None = None
    step: int = 0
    carrying: bool = False
    grasp_held: bool = False
    rejoin: bool = False
    next_id: int = 1
    summary: JobSummary = field(default_factory=JobSummary)


@dataclass(slots=True)
class _Command:
    verb: str
    request: StartRequest | None
    reason: str
    reply: asyncio.Future[dict[str, object]]


class Job:
    """Runs loading jobs on a backend: owns the chart, does each state's work, answers commands."""

    def __init__(
        self,
        backend: Backend,
        config: Config,
        publish: Publish,
        associate: Associate,
        *,
        chart: StateChart | None = None,
        executor: concurrent.futures.Executor | None = None,
    ) -> None:
        """``executor`` (a process pool) runs placement planning off this process, so its CPU time does not
        hold the GIL against the event loop; without it, planning runs in a thread."""
        self.backend = backend
        self._clock = backend.clock
        self._executor = executor
        self.config = config
        self.chart = chart or StateChart()
        self._publish = publish
        self._associate = associate
        self._inbox: asyncio.Queue[_Command | tuple[int, Outcome]] = asyncio.Queue()
        self._work: asyncio.Task[None] | None = None
        self._generation = 0
        self._ctx = _Context(planner=self._planner_options(PlannerRequest()))
        self._transitions = 0
        self._force_down = 0  # FSR lost/stale reports since it was last restored
        self.finished = asyncio.Event()
        self.chart.subscribe(self._on_transition)

    # --- public surface ------------------------------------------------------------------------------------

    @property
    def summary(self) -> JobSummary:
        return self._ctx.summary

    def status(self) -> dict[str, object]:
        """The ``state`` payload: where the chart is and how far the job got."""
        ctx = self._ctx
        return {
            "state": self.chart.state,
            "mugs_total": len(ctx.counter) + len(ctx.on_tray),
            "mugs_planned": ctx.summary.planned,
            "mugs_placed": len(ctx.on_tray),
            "mugs_failed": ctx.summary.failed,
            "current_mug": ctx.current.mug_id if ctx.current else None,
            "transitions": self._transitions,
            "t": self._clock.now(),
        }

    async def command(self, verb: str, request: StartRequest | None = None) -> dict[str, object]:
        """Queue a command for the control task and wait for its reply; ``CommandRefused`` when refused."""
        return await self._submit(_Command(verb, request, "", asyncio.get_running_loop().create_future()))

    async def fault(self, reason: str) -> None:
        """A device failed outside a state's work (e.g. while reading telemetry): enter fault."""
        with contextlib.suppress(CommandRefused):
            await self._submit(_Command("fault", None, reason, asyncio.get_running_loop().create_future()))

    def device_event(self, event: Mapping[str, object]) -> None:
        """A driver's fault or recovery (``backend.device_event_payload``), on the event loop: published on
        ``events``; a lost bus, and a silent or unplugged force sensor while a job works (a drop could no
        longer be seen), fault the job. Servo faults are only reported here: the gripper recovers overloads
        itself, and a fault that stands reaches the job as the driver's exception."""
        kind = str(event.get("kind", ""))
        self._publish("events", {**event, "state": self.chart.state})
        reason = f"{kind} on {event.get('port', event.get('device', '?'))}"
        if "error" in event:
            reason += f": {event['error']}"
        if kind == "bus_lost":
            asyncio.get_running_loop().create_task(self.fault(reason))
        elif kind in ("fsr_lost", "fsr_stale"):
            self._force_down += 1
            if top_level(self.chart.state) in _WORKING:
                asyncio.get_running_loop().create_task(self._fault_unless_force_back(reason))
        elif kind == "fsr_restored":
            self._force_down = 0

    async def _fault_unless_force_back(self, reason: str, *, grace_s: float = _FORCE_GRACE_S) -> None:
        """Fault the job when the force sensor is still lost or silent after ``grace_s``: a short stall of
        the event loop must not end a job, a sensor that stays away must (no drop could be seen)."""
        await self._clock.sleep(grace_s)
        if self._force_down and top_level(self.chart.state) in _WORKING:
            await self.fault(reason)

    async def _submit(self, cmd: _Command) -> dict[str, object]:
        await self._inbox.put(cmd)
        return await cmd.reply

    async def run(self) -> None:
        """The control task: fire each outcome or command in turn. Cancel it to stop (after ``shutdown``)."""
        while True:
            item = await self._inbox.get()
            if isinstance(item, _Command):
                await self._handle(item)
                continue
            generation, outcome = item
            if generation != self._generation:
                continue  # the state this work belonged to was left already
            await self._advance(outcome)

    async def shutdown(self) -> None:
        """Stop any motion safely (the process is exiting)."""
        await self._cancel_work()
        with contextlib.suppress(DriverError, BusLost):
            await self.backend.arm.stop()

    # --- commands ------------------------------------------------------------------------------------------

    async def _handle(self, cmd: _Command) -> None:
        try:
            result = await self._execute(cmd)
        except CommandRefused as e:
            if not cmd.reply.done():
                cmd.reply.set_exception(e)
            return
        if not cmd.reply.done():
            cmd.reply.set_result(result)

    async def _execute(self, cmd: _Command) -> dict[str, object]:
        verb = cmd.verb
        if not self.chart.can(verb):
            raise CommandRefused(f"cannot {verb} in state {self.chart.state}")
        if verb == "start":
            if self._force_down:
                raise CommandRefused(
                    "the gripper's force sensor is not reporting (lost or silent); check the FSR Arduino"
                )
            self._begin(cmd.request or StartRequest())
            await self._fire(Outcome("start"))
            return {"state": self.chart.state}
        if verb in ("pause", "stop"):
            await self._cancel_work()
            await self._safe_stop()
            await self._fire(Outcome(verb))
            return {"state": self.chart.state}
        if verb == "fault":
            await self._cancel_work()
            await self._advance(Outcome("fault", {"reason": cmd.reason}))
            return {"state": self.chart.state}
        if verb == "estop":
            await self._cancel_work()
            await self._safe_stop()
            with contextlib.suppress(DriverError, BusLost):
                await self.backend.arm.relax()
            await self._fire(Outcome("estop"))
            return {"state": self.chart.state}
        if verb in ("resume", "reset"):
            self._ctx.rejoin = verb == "resume"
            await self._fire(Outcome(verb))
            return {"state": self.chart.state}
        raise CommandRefused(f"unknown command {verb!r}")

    def _begin(self, request: StartRequest) -> None:
        options = self._planner_options(request.planner)
        if request.dataset is not None or request.mugs is not None:
            if self.backend.counter is None:
                raise CommandRefused(
                    "dataset and mugs set up a simulated counter; this backend is real hardware"
                )
            try:
                tray = self.backend.counter.set_counter(dataset=request.dataset, mugs=request.mugs)
            except ValueError as e:
                raise CommandRefused(str(e)) from e
            if tray != self.backend.tray and self.backend.motion_for is not None:
                self.backend.motion = self.backend.motion_for(tray)
            self.backend.tray = tray
            self._event("scene_set", scene=self.backend.scene())  # the recording's header has the first
            previous = _Context(planner=options)  # a new scene: the tray starts empty
        else:
            previous = self._ctx  # the same scene: what earlier jobs put on the tray is still there
        self._ctx = _Context(
            planner=options,
            on_tray=list(previous.on_tray),
            tray_mugs=list(previous.tray_mugs),
            next_id=previous.next_id,
        )
        self._ctx.summary.started_at, self._ctx.summary.clock = self._clock.monotonic(), self._clock
        self.finished.clear()

    def _planner_options(self, req: PlannerRequest) -> PlanOptions:
        p = self.config.planner
        return PlanOptions(
            method=req.method or p.method,
            cost=req.cost or p.cost,
            fitness=req.fitness or p.fitness,
            time_limit_s=req.time_limit_s or p.time_limit_s,
            seed=p.seed if req.seed is None else req.seed,
        )

    # --- driving the chart ---------------------------------------------------------------------------------

    async def _advance(self, outcome: Outcome) -> None:
        if outcome.trigger == "fault":
            await self._safe_stop()
            log.error("fault", reason=outcome.values.get("reason", ""))
            self._event("fault", **dict(outcome.values))
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
        self._event("transition", trigger=change.trigger, source=change.source, dest=change.dest, **detail)
        self._publish("state", self.status())
        if change.dest in ("done", "fault", "estop") or (change.dest == "idle" and change.trigger == "stop"):
            self._ctx.summary.ended_at = self._clock.monotonic()
            self._ctx.summary.end_state = change.dest
            self.finished.set()

    def _start_work(self) -> None:
        self._generation += 1
        leaf = self.chart.state
        if top_level(leaf) not in _WORKING:
            return
        generation = self._generation
        self._work = asyncio.create_task(self._run_work(leaf, generation), name=f"work:{leaf}")

    async def _run_work(self, leaf: str, generation: int) -> None:
        bound = log.bind(state=leaf, mug_id=self._ctx.current.mug_id if self._ctx.current else None)
        try:
            outcome = await self._work_for(leaf)
        except asyncio.CancelledError:
            raise
        except (DriverError, BusLost, LimitViolation) as e:
            bound.error("device_failed", error=str(e))
            outcome = Outcome("fault", {"reason": f"{type(e).__name__}: {e}"})
        except MotionRefused as e:
            outcome = Outcome("fault", {"reason": f"motion refused: {e}"})
        except Exception as e:  # a bug must not leave the job hanging in a state with no work
            bound.exception("work_crashed")
            outcome = Outcome("fault", {"reason": f"internal error in {leaf}: {e!r}"})
        await self._inbox.put((generation, outcome))

    async def _cancel_work(self) -> None:
        self._generation += 1
        work, self._work = self._work, None
        if work is not None and not work.done():
            work.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await work

    async def _safe_stop(self) -> None:
        with contextlib.suppress(DriverError, BusLost):
            await self.backend.arm.stop()
        with contextlib.suppress(DriverError, BusLost):
            await self.backend.gripper.stop()

    # --- the work of each state ----------------------------------------------------------------------------

    async def _work_for(self, leaf: str) -> Outcome:
        if leaf == "detect":
            return await self._detect()
        if leaf == "plan":
            return await self._plan()
        if leaf == "recover_lost_mug":
            return await self._recover()
        if leaf.endswith(".verify"):
            return await self._verify(leaf)
        return await self._steps(leaf)

    async def _detect(self) -> Outcome:
        ctx = self._ctx
        previous = set(ctx.counter) - ctx.given_up
        seen = await self._look()
        ctx.counter = {d.mug_id: self._pose(d) for d in seen}
        came = set(ctx.counter) - ctx.given_up - previous
        went = previous - set(ctx.counter)
        if previous and (came or went):
            self._event("counter_changed", came=sorted(came), went=sorted(went))
        ctx.needs_plan = ctx.needs_plan or bool(came or went)
        ctx.summary.detected = max(ctx.summary.detected, len(ctx.counter) + len(ctx.on_tray))
        if ctx.needs_plan:
            return Outcome("detected", {"needs_plan": True, "has_next_mug": False})
        return Outcome("detected", {"needs_plan": False, "has_next_mug": await self._prepare_next()})

    async def _plan(self) -> Outcome:
        ctx = self._ctx
        try:
            problem = self._problem()
            dynamics = self._dynamics_spec()
            if self._executor is None:
                result = await asyncio.to_thread(plan_placement, problem, ctx.planner, dynamics)
            else:
                result = await asyncio.get_running_loop().run_in_executor(
                    self._executor, plan_placement, problem, ctx.planner, dynamics
                )
        except InvalidProblem as e:
            self._event("warning", message=f"placement planning refused the problem: {e}")
            ctx.queue = []
            ctx.needs_plan = False
            return Outcome("planned", {"has_next_mug": False})
        ctx.queue = []
        for placed in sorted(result.placed, key=lambda p: p.order):
            if placed.id not in ctx.counter or placed.id in ctx.given_up:
                continue
            bx, by = problem.brim_centre_on_tray(placed.type, placed.x_mm, placed.y_mm)
            wx, wy = problem.to_world_mm(bx, by)
            slot = TraySlot(placed.id, placed.type, wx / 1000.0, wy / 1000.0, placed.rotated)
            ctx.queue.append(
                (slot, TrayMug(placed.id, placed.type, placed.x_mm, placed.y_mm, placed.rotated))
            )
        ctx.summary.planned = len(ctx.on_tray) + len(ctx.queue)
        ctx.needs_plan = False
        payload = result.to_json()
        payload["slots"] = [
            {
                "id": s.mug_id,
                "type": s.type,
                "x_m": round(s.x_m, 5),
                "y_m": round(s.y_m, 5),
                "rotated": s.rotated,
            }
            for s, _ in ctx.queue
        ]
        payload["t"] = self._clock.now()
        self._publish("plan", payload)
        return Outcome("planned", {"has_next_mug": await self._prepare_next()})

    async def _recover(self) -> Outcome:
        ctx = self._ctx
        current = ctx.current
        ctx.carrying = False
        await self._gripper_action(self.backend.gripper.open())
        target = current.mug_id if current is not None and current.mug_id in ctx.counter else ""
        seen = await self._look(target_id=target)
        ctx.counter = {d.mug_id: self._pose(d) for d in seen}
        if current is None:
            ctx.needs_plan = True
            return Outcome("recovered", {"mug_found": False})
        mug = ctx.counter.get(current.mug_id)
        attempts = ctx.attempts.get(current.mug_id, 0) + 1
        ctx.attempts[current.mug_id] = attempts
        if (
            mug is not None
            and attempts < self.config.grasp.max_attempts
            and await self._plan_cycle(mug, current, retry=True) is not None
        ):
            self._event("mug_found", mug_id=current.mug_id, x_m=mug.x_m, y_m=mug.y_m)
            return Outcome("recovered", {"mug_found": True})
        reason = "not seen on the counter" if mug is None else f"given up after {attempts} attempts"
        self._give_up(current.mug_id, reason)
        ctx.current = None
        ctx.cycle = None
        ctx.needs_plan = True
        return Outcome("recovered", {"mug_found": False})

    async def _verify(self, leaf: str) -> Outcome:
        """The grasp holds when the gripper's close said so and the debounced FSR agrees within
        ``_GRASP_CONFIRM_S`` (reading ``holding()`` at once would race the reader's debounce)."""
        ctx = self._ctx
        held = ctx.grasp_held and await self._force_confirms()
        ctx.carrying = held
        if not held:
            ctx.summary.grasp_failures += 1
            self._event("grasp_failed", state=leaf, mug_id=ctx.current.mug_id if ctx.current else "")
        return Outcome("verified", {"grasp_held": held})

    async def _force_confirms(self, *, timeout_s: float = _GRASP_CONFIRM_S) -> bool:
        """Whether the FSR reader's debounced ``holding()`` turns (or is) true within ``timeout_s``."""
        deadline = self._clock.monotonic() + timeout_s
        while not self.backend.force.holding():
            if self._clock.monotonic() >= deadline:
                return False
            await self._clock.sleep(_GRASP_POLL_S)
        return True

    async def _steps(self, leaf: str) -> Outcome:
        """Execute the current cycle's steps of one phase, from where a pause left them."""
        ctx = self._ctx
        cycle = ctx.cycle
        if cycle is None:
            raise RuntimeError(f"state {leaf} entered without a cycle plan")
        while ctx.step < len(cycle.steps) and cycle.steps[ctx.step].phase == leaf:
            step = cycle.steps[ctx.step]
            if step.kind is StepKind.MOVE:
                if not await self._move(step, watch=leaf in CARRYING and ctx.carrying):
                    ctx.summary.drops += 1
                    ctx.carrying = False
                    self._event("mug_dropped", state=leaf, mug_id=cycle.mug_id)
                    return Outcome("mug_dropped", {})
            elif step.kind is StepKind.CLOSE:
                g = self.config.grasp
                result = await self._gripper_action(
                    self.backend.gripper.close_on_mug(
                        force_threshold_n=g.force_threshold_n, min_aperture_m=g.min_aperture_m
                    )
                )
                ctx.grasp_held = result.held
            else:
                await self._gripper_action(self.backend.gripper.open(step.aperture_m))
                ctx.carrying = False
                if leaf == "place.release":
                    self._placed()
            ctx.step += 1
        if leaf == "place.retreat":
            ctx.current = None
            ctx.cycle = None
        return Outcome("next", {})

    # --- helpers -------------------------------------------------------------------------------------------

    async def _move(self, step: Step, *, watch: bool) -> bool:
        """Follow one MOVE step; with ``watch``, poll the force sensor and stop the arm when the mug drops
        (returns False). After a resume the step is joined where it was interrupted."""
        traj = step.trajectory
        if traj is None:
            raise MotionRefused(f"step {step.phase} is a move without a trajectory")
        if self._ctx.rejoin:
            traj = await self._rejoin(traj)
            self._ctx.rejoin = False
        arm = self.backend.arm
        period = self.config.daemon.drop_check_period_s if watch else None
        follow = asyncio.create_task(arm.follow(traj), name=f"follow:{step.phase}")
        try:
            while not follow.done():
                await self._clock.wait(follow, period)
                if watch and not follow.done() and not self.backend.force.holding():
                    return False
            follow.result()
            return not watch or self.backend.force.holding()
        finally:
            if not follow.done():
                follow.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await follow
                await arm.stop()

    async def _rejoin(self, traj: JointTrajectory) -> JointTrajectory:
        """The part of ``traj`` still to do from where the arm is: the whole of it when the arm is at its
        start, else a bridging move to the nearest sample followed by the rest."""
        js = await self.backend.arm.read_joints()
        q = np.asarray(js.position_rad, dtype=np.float64)
        positions = np.asarray(traj.positions, dtype=np.float64)
        distance = np.max(np.abs(positions - q), axis=1)
        nearest = int(np.argmin(distance))
        if nearest == 0 and distance[0] <= _ON_PATH_RAD:
            return traj
        rest_times = traj.times[nearest:] - traj.times[nearest]
        rest = JointTrajectory(traj.names, rest_times, positions[nearest:], label=f"{traj.label}:rejoined")
        if distance[nearest] <= _ON_PATH_RAD:
            return rest
        bridge = self.backend.motion.plan_move(
            q.tolist(), positions[nearest].tolist(), label=f"{traj.label}:bridge"
        )
        times = np.concatenate([bridge.times, rest.times[1:] + bridge.times[-1]])
        joined = np.vstack([bridge.positions, rest.positions[1:]])
        return JointTrajectory(traj.names, times, joined, label=rest.label)

    async def _gripper_action(self, action: Awaitable[T]) -> T:
        """Await a gripper action; if the state is cancelled meanwhile, stop the gripper where it is."""
        try:
            return await action
        except asyncio.CancelledError:
            await self.backend.gripper.stop()
            raise

    async def _look(self, *, target_id: str = "") -> list[Detection]:
        """Observe the counter and give each detection the id of the known mug it is, or a new id."""
        ctx = self._ctx
        obs = await self.backend.observer.observe()
        tray = self.backend.tray
        # Mugs standing on the tray are the job's own work (it knows them); only counter mugs are to load.
        on_counter = tuple(d for d in obs.detections if not tray.contains(d.x_m, d.y_m))
        known = [
            Detection(m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, 1.0, m.mug_id, m.handle_seen)
            for m in ctx.counter.values()
        ]
        associated = (
            list(self._associate(known, on_counter, target_id=target_id)) if known else list(on_counter)
        )
        out = []
        for d in sorted(associated, key=lambda d: (d.mug_id == "", -d.x_m, d.y_m)):
            if not d.mug_id:
                d = replace(d, mug_id=f"m{ctx.next_id}")
                ctx.next_id += 1
            out.append(d)
        payload = observation_payload(replace(obs, detections=tuple(out)), t=self._clock.now())
        if obs.depth_preview is not None:
            payload["depth_preview"] = depth_preview_payload(obs.depth_preview)
        self._publish("detections", payload)
        return out

    @staticmethod
    def _pose(d: Detection) -> MugPose:
        return MugPose(d.mug_id, d.type, d.x_m, d.y_m, d.handle_yaw_rad, d.upside_down, d.handle_seen)

    def _give_up(self, mug_id: str, reason: str) -> None:
        """Leave a mug on the counter for good (it stays known, so it is not mistaken for a new one)."""
        ctx = self._ctx
        ctx.given_up.add(mug_id)
        ctx.summary.failed = len(ctx.given_up)
        self._event("mug_given_up", mug_id=mug_id, reason=reason)

    async def _prepare_next(self) -> bool:
        """Take the next planned mug whose cycle can be planned. When the motion planner can fill a slot with
        another mug of the same type (``SlotPlanner``), a blocked mug is swapped for a reachable one. A slot
        no motion reaches now keeps its place in the queue and is tried again after the next mug (taking
        that mug off the counter may clear the way); it is given up only when no queued slot can be
        planned."""
        ctx = self._ctx
        i = 0
        while i < len(ctx.queue):
            slot, tray_mug = ctx.queue[i]
            mug = ctx.counter.get(slot.mug_id)
            del ctx.queue[i]
            if mug is None or slot.mug_id in ctx.given_up:
                continue
            ctx.current_tray_mug = tray_mug
            motion = self.backend.motion
            if isinstance(motion, SlotPlanner):
                if await self._plan_for_slot(motion, slot, tray_mug):
                    return True
            elif await self._plan_cycle(mug, slot, retry=False) is not None:
                return True
            ctx.queue.insert(i, (slot, tray_mug))
            i += 1
        for slot, _ in ctx.queue:
            if slot.mug_id in ctx.counter and slot.mug_id not in ctx.given_up:
                self._give_up(slot.mug_id, "no motion reaches it")
        ctx.queue = []
        ctx.current = None
        ctx.cycle = None
        return False

    async def _plan_for_slot(self, motion: SlotPlanner, slot: TraySlot, tray_mug: TrayMug) -> bool:
        """Plan the cycle filling ``slot`` with its mug or, when that one is blocked, with the nearest
        reachable counter mug of the same type; the two mugs swap their places in the plan."""
        ctx = self._ctx
        js = await self.backend.arm.read_joints()
        counter = tuple(m for m in ctx.counter.values() if m.mug_id not in ctx.given_up)
        try:
            mug, cycle = await asyncio.to_thread(
                motion.plan_for_slot, js.position_rad, slot, counter, tuple(ctx.on_tray)
            )
        except MotionRefused as e:
            self._event("motion_refused", mug_id=slot.mug_id, reason=str(e))
            return False
        if mug.mug_id != slot.mug_id:
            # The swapped-in mug's own slot (same type, so the same footprint) goes to the blocked mug.
            ctx.queue = [
                (replace(s, mug_id=slot.mug_id), replace(t, id=slot.mug_id))
                if s.mug_id == mug.mug_id
                else (s, t)
                for s, t in ctx.queue
            ]
            self._event(
                "mug_swapped", slot_for=slot.mug_id, mug_id=mug.mug_id, reason="blocked or out of reach"
            )
            slot = replace(slot, mug_id=mug.mug_id)
            ctx.current_tray_mug = replace(tray_mug, id=mug.mug_id)
        self._adopt_cycle(mug, slot, cycle, retry=False)
        return True

    async def _plan_cycle(self, pose: MugPose, slot: TraySlot, *, retry: bool) -> CyclePlan | None:
        ctx = self._ctx
        js = await self.backend.arm.read_joints()
        try:
            others = tuple(m for m in ctx.counter.values() if m.mug_id != pose.mug_id)
            cycle = await asyncio.to_thread(
                functools.partial(self.backend.motion.plan_cycle, counter=others),
                js.position_rad,
                pose,
                slot,
                tuple(ctx.on_tray),
            )
        except MotionRefused as e:
            self._event("motion_refused", mug_id=pose.mug_id, reason=str(e))
            return None
        self._adopt_cycle(pose, slot, cycle, retry=retry)
        return cycle

    def _adopt_cycle(self, pose: MugPose, slot: TraySlot, cycle: CyclePlan, *, retry: bool) -> None:
        """Make ``cycle`` (taking ``pose`` to ``slot``) the current one, from its first step."""
        ctx = self._ctx
        bad = [s.phase for s in cycle.steps if s.phase not in CYCLE_PHASES]
        if bad:
            raise MotionRefused(
                f"cycle plan for {pose.mug_id} has steps for unknown phases {sorted(set(bad))}"
            )
        ctx.current = slot
        ctx.cycle = cycle
        ctx.step = 0
        ctx.grasp_held = False
        self._event(
            "cycle_planned",
            mug_id=pose.mug_id,
            retry=retry,
            duration_s=round(cycle.duration_s, 3),
            energy_j=round(cycle.energy_j, 3),
        )

    def _placed(self) -> None:
        ctx = self._ctx
        if ctx.current is None:
            return
        handle_yaw = ctx.cycle.handle_yaw_rad if ctx.cycle is not None else None
        ctx.on_tray.append(replace(ctx.current, handle_yaw_rad=handle_yaw))
        if ctx.current_tray_mug is not None:
            ctx.tray_mugs.append(ctx.current_tray_mug)
        ctx.counter.pop(ctx.current.mug_id, None)
        ctx.summary.placed = len(ctx.on_tray)
        placed = {"mug_id": ctx.current.mug_id, "x_m": ctx.current.x_m, "y_m": ctx.current.y_m}
        if handle_yaw is not None:
            placed["handle_yaw_rad"] = round(handle_yaw, 4)
        self._event("mug_placed", **placed)

    def _dynamics_spec(self) -> CyclePlannerSpec | None:
        """The cell whose arm dynamics cost the placement's moves (``planner.energy_model = "dynamics"``);
        None for the thesis's potential-energy proxy."""
        if self.config.planner.energy_model != "dynamics":
            return None
        return CyclePlannerSpec(self.config.cell, self.backend.tray, self.config.mug_types)

    def _problem(self) -> Problem:
        ctx = self._ctx
        tray = self.backend.tray
        types = {
            m.name: PlanMugType(m.name, m.diameter_mm, m.width_mm, m.height_mm, m.mass_kg)
            for m in self.config.mug_types
        }
        mugs = tuple(
            PlanMug(m.mug_id, m.type, m.x_m * 1000.0, m.y_m * 1000.0)
            for m in ctx.counter.values()
            if m.mug_id not in ctx.given_up
        )
        return Problem(
            tray_size_mm=tray.size_mm,
            tray_origin_mm=(tray.origin_m[0] * 1000.0, tray.origin_m[1] * 1000.0),
            mugs=mugs,
            mug_types=types,
            placed=tuple(ctx.tray_mugs),
            tolerance_mm=self.config.planner.tolerance_mm,
            allow_rotation=self.config.planner.allow_rotation,
        )

    def _event(self, kind: str, **detail: Any) -> None:
        self._publish("events", {"kind": kind, "state": self.chart.state, "t": self._clock.now(), **detail})
