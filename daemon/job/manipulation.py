"""The manipulation states ``side_grasp``, ``flip`` and ``place``, one stage per leaf of the chart.

Each stage executes the current cycle plan's steps for its leaf (``Step.phase``): MOVE follows a trajectory
(watching the force sensor in the leaves that carry the mug), CLOSE closes the gripper on the mug, OPEN lets
go. ``verify`` stages check the grasp instead, ``place.release`` records the placement, ``place.retreat``
ends the cycle. Every motion runs inside ``try/finally`` that stops the arm (and the gripper), so a stage
cancelled by pause, stop, fault or estop leaves the arm holding still; a resumed move joins the interrupted
trajectory at its nearest sample.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable
from dataclasses import replace
from typing import TypeVar

import numpy as np

from daemon.job.context import JobContext, Outcome
from daemon.job.services import Services
from daemon.job.unit import Stages, Unit
from drivers.interfaces import JointTrajectory
from planning.interfaces import MotionRefused, Step, StepKind
from statechart.chart import CARRYING
from wire.messages import UNSET, GraspFailedEvent, MugDroppedEvent, MugPlacedEvent

# After a pause, a move is joined at its nearest sample; within this of it, without a bridging move.
_ON_PATH_RAD = 0.02
# A held grasp is confirmed by the FSR reader's debounced ``holding()``, which turns true only after the force
# has stayed above its threshold for the debounce time (30 ms by default) and a sample has arrived after it.
# The verify waits for that, polling, for at most this long: several debounce windows and sample periods.
_GRASP_CONFIRM_S = 0.3
_GRASP_POLL_S = 0.005

T = TypeVar("T")


class FollowSteps(Unit):
    """Execute the cycle's steps of this leaf, from where a pause left them; ``next`` when done,
    ``mug_dropped`` when the force sensor lost the carried mug."""

    reads = frozenset({"cycle"})
    writes = frozenset({"step", "carrying", "grasp_held", "rejoin", "summary"})

    def __init__(self, leaf: str) -> None:
        super().__init__(leaf, ("next", "mug_dropped") if leaf in CARRYING else ("next",))

    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        cycle = ctx.cycle
        if cycle is None:
            raise RuntimeError(f"state {self.leaf} entered without a cycle plan")
        while ctx.step < len(cycle.steps) and cycle.steps[ctx.step].phase == self.leaf:
            step = cycle.steps[ctx.step]
            if step.kind is StepKind.MOVE:
                if not await _move(services, ctx, step, watch=self.leaf in CARRYING and ctx.carrying):
                    ctx.summary.drops += 1
                    ctx.carrying = False
                    services.event(MugDroppedEvent(state=self.leaf, mug_id=cycle.mug_id))
                    return Outcome("mug_dropped", {})
            elif step.kind is StepKind.CLOSE:
                g = services.config.grasp
                close = services.backend.gripper.close_on_mug(
                    force_threshold_n=g.force_threshold_n, min_aperture_m=g.min_aperture_m
                )
                ctx.grasp_held = (await gripper_action(services, close)).held
            else:
                await gripper_action(services, services.backend.gripper.open(step.aperture_m))
                ctx.carrying = False
                self.opened(services, ctx)
            ctx.step += 1
        self.finished(ctx)
        return Outcome("next", {})

    def opened(self, services: Services, ctx: JobContext) -> None:
        """The gripper let go during this leaf."""

    def finished(self, ctx: JobContext) -> None:
        """Every step of this leaf is done."""


class PlaceRelease(FollowSteps):
    """``place.release``: let go over the slot; the mug is on the tray (``mug_placed``)."""

    reads = FollowSteps.reads | {"current", "current_tray_mug"}
    writes = FollowSteps.writes | {"on_tray", "tray_mugs", "counter"}

    def opened(self, services: Services, ctx: JobContext) -> None:
        slot = ctx.current
        if slot is None:
            return
        handle_yaw = ctx.cycle.handle_yaw_rad if ctx.cycle is not None else None
        ctx.on_tray.append(replace(slot, handle_yaw_rad=handle_yaw))
        if ctx.current_tray_mug is not None:
            ctx.tray_mugs.append(ctx.current_tray_mug)
        ctx.counter.pop(slot.mug_id, None)
        ctx.summary.placed = len(ctx.on_tray)
        yaw = UNSET if handle_yaw is None else round(handle_yaw, 4)
        services.event(MugPlacedEvent(mug_id=slot.mug_id, x_m=slot.x_m, y_m=slot.y_m, handle_yaw_rad=yaw))


class PlaceRetreat(FollowSteps):
    """``place.retreat``: back off the placed mug; the cycle is over."""

    writes = FollowSteps.writes | {"current", "cycle"}

    def finished(self, ctx: JobContext) -> None:
        ctx.current = None
        ctx.cycle = None


class VerifyGrasp(Unit):
    """The grasp holds when the gripper's close said so and the debounced FSR agrees within
    ``_GRASP_CONFIRM_S`` (reading ``holding()`` at once would race the reader's debounce); ``verified``
    with ``grasp_held``."""

    reads = frozenset({"grasp_held", "current"})
    writes = frozenset({"carrying", "summary"})

    def __init__(self, leaf: str) -> None:
        super().__init__(leaf, ("verified",))

    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        held = ctx.grasp_held and await _force_confirms(services)
        ctx.carrying = held
        if not held:
            ctx.summary.grasp_failures += 1
            mug_id = ctx.current.mug_id if ctx.current else ""
            services.event(GraspFailedEvent(state=self.leaf, mug_id=mug_id))
        return Outcome("verified", {"grasp_held": held})


SIDE_GRASP = Stages(
    "side_grasp",
    (
        FollowSteps("side_grasp.approach"),
        FollowSteps("side_grasp.close"),
        VerifyGrasp("side_grasp.verify"),
        FollowSteps("side_grasp.lift"),
    ),
)
FLIP = Stages(
    "flip",
    (
        FollowSteps("flip.transit"),
        FollowSteps("flip.turn"),
        FollowSteps("flip.set_down"),
        FollowSteps("flip.release"),
        FollowSteps("flip.regrasp"),
        FollowSteps("flip.close"),
        VerifyGrasp("flip.verify"),
        FollowSteps("flip.lift"),
    ),
)
PLACE = Stages(
    "place",
    (
        FollowSteps("place.transit"),
        FollowSteps("place.descend"),
        PlaceRelease("place.release"),
        PlaceRetreat("place.retreat"),
    ),
)


async def gripper_action(services: Services, action: Awaitable[T]) -> T:
    """Await a gripper action; if the state is cancelled meanwhile, stop the gripper where it is."""
    try:
        return await action
    except asyncio.CancelledError:
        await services.backend.gripper.stop()
        raise


async def _force_confirms(services: Services, *, timeout_s: float = _GRASP_CONFIRM_S) -> bool:
    """Whether the FSR reader's debounced ``holding()`` turns (or is) true within ``timeout_s``."""
    deadline = services.monotonic() + timeout_s
    while not services.backend.force.holding():
        if services.monotonic() >= deadline:
            return False
        await services.sleep(_GRASP_POLL_S)
    return True


async def _move(services: Services, ctx: JobContext, step: Step, *, watch: bool) -> bool:
    """Follow one MOVE step; with ``watch``, poll the force sensor and stop the arm when the mug drops
    (returns False). After a resume the step is joined where it was interrupted."""
    traj = step.trajectory
    if traj is None:
        raise MotionRefused(f"step {step.phase} is a move without a trajectory")
    if ctx.rejoin:
        traj = await _rejoin(services, traj)
        ctx.rejoin = False
    arm = services.backend.arm
    force = services.backend.force
    period = services.config.daemon.drop_check_period_s if watch else None
    follow = asyncio.create_task(arm.follow(traj), name=f"follow:{step.phase}")
    try:
        while not follow.done():
            await services.wait_done(follow, period)
            if watch and not follow.done() and not force.holding():
                return False
        follow.result()
        return not watch or force.holding()
    finally:
        if not follow.done():
            follow.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await follow
            await arm.stop()


async def _rejoin(services: Services, traj: JointTrajectory) -> JointTrajectory:
    """The part of ``traj`` still to do from where the arm is: the whole of it when the arm is at its
    start, else a bridging move to the nearest sample followed by the rest."""
    js = await services.backend.arm.read_joints()
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
    bridge = services.backend.motion.plan_move(
        q.tolist(), positions[nearest].tolist(), label=f"{traj.label}:bridge"
    )
    times = np.concatenate([bridge.times, rest.times[1:] + bridge.times[-1]])
    joined = np.vstack([bridge.positions, rest.positions[1:]])
    return JointTrajectory(traj.names, times, joined, label=rest.label)
