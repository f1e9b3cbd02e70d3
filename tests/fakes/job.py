"""Stand-ins for the physical world in job tests: a counter of mugs, an arm that takes time to move, a gripper
whose grasps can be made to fail, a force sensor whose mug can be made to drop, and a motion planner test
double whose trajectories name the mug and phase they belong to."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from daemon.backend import Backend
from daemon.clock import RealClock, SessionClock
from description.cell import Tray
from drivers.errors import BusLost
from drivers.interfaces import ForceReading, GraspResult, GripperState, JointState, JointTrajectory
from perception.interfaces import Detection, Observation
from planning.interfaces import CyclePlan, MotionRefused, MugPose, Step, StepKind, TraySlot
from statechart.chart import CYCLE_PHASES

NAMES = ("j1", "j2", "j3", "j4", "j5")
MOVE_S = 0.004  # each planned move takes this long


@dataclass
class FakeWorld:
    counter: dict[str, Detection]
    held: str | None = None
    loose: str | None = None
    placed: list[str] = field(default_factory=list)
    target: str | None = None
    fail_grasps: int = 0
    always_fail: set[str] = field(default_factory=set)
    drop_in_phase: str | None = None
    bus_lost_in_phase: str | None = None
    phase: str = ""
    q: np.ndarray = field(default_factory=lambda: np.zeros(5))
    log: list[str] = field(default_factory=list)
    original: dict[str, Detection] = field(default_factory=dict)
    hold_in_phase: str | None = None
    hold_in_close: bool = False
    holding_still: asyncio.Event = field(default_factory=asyncio.Event)
    # Where each mug's cycle was planned to set it down (true id -> brim centre), and where the placed ones
    # stand: the observer sees them there, as a camera over the tray would.
    slot_for: dict[str, tuple[float, float]] = field(default_factory=dict)
    placed_at: dict[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.original = dict(self.counter)


class FakeArm:
    joint_names = NAMES

    def __init__(self, world: FakeWorld) -> None:
        self.w = world

    async def read_joints(self) -> JointState:
        q = tuple(float(v) for v in self.w.q)
        return JointState(0.0, NAMES, q, (0.0,) * 5, (0.0,) * 5)

    async def follow(self, trajectory: JointTrajectory) -> None:
        self.w.phase = trajectory.label
        self.w.log.append(f"follow:{trajectory.label}")
        n = len(trajectory.times)
        for i in range(n):
            if self.w.bus_lost_in_phase and trajectory.label.startswith(self.w.bus_lost_in_phase):
                raise BusLost("bus on /dev/fake is gone", port="/dev/fake")
            if self.w.drop_in_phase and trajectory.label.startswith(self.w.drop_in_phase) and i == n // 2:
                self.w.drop_in_phase = None
                self.w.counter[self.w.held or ""] = self.w.original[self.w.held or ""]
                self.w.held = None
            self.w.q = np.array(trajectory.positions[i], dtype=np.float64)
            if self.w.hold_in_phase and trajectory.label.startswith(self.w.hold_in_phase) and i == n // 2:
                self.w.hold_in_phase = None
                self.w.holding_still.set()
                await asyncio.Event().wait()  # until cancelled
            await asyncio.sleep(MOVE_S / n)

    async def stop(self) -> None:
        self.w.log.append("arm.stop")

    async def relax(self) -> None:
        self.w.log.append("arm.relax")


class FakeGripper:
    def __init__(self, world: FakeWorld) -> None:
        self.w = world

    async def read(self) -> GripperState:
        return GripperState(0.0, 0.05 if self.w.held else 0.12, 0.0)

    async def open(self, aperture_m: float | None = None) -> None:
        self.w.log.append(f"open:{self.w.phase}")
        await asyncio.sleep(0.001)
        if self.w.held is not None:
            if self.w.phase.startswith("place"):
                self.w.placed.append(self.w.held)
                if self.w.held in self.w.slot_for:
                    self.w.placed_at[self.w.held] = self.w.slot_for[self.w.held]
            else:
                self.w.loose = self.w.held
            self.w.held = None

    async def close_on_mug(self, *, force_threshold_n: float, min_aperture_m: float) -> GraspResult:
        self.w.log.append(f"close:{self.w.phase}")
        if self.w.hold_in_close:
            self.w.hold_in_close = False
            self.w.holding_still.set()
            await asyncio.Event().wait()  # until cancelled
        await asyncio.sleep(0.001)
        mug = self.w.loose or self.w.target
        if mug is None or self.w.fail_grasps > 0 or mug in self.w.always_fail:
            self.w.fail_grasps = max(0, self.w.fail_grasps - 1)
            return GraspResult(False, 0.0, min_aperture_m, "closed on nothing")
        self.w.held, self.w.loose = mug, None
        self.w.counter.pop(mug, None)
        return GraspResult(True, force_threshold_n + 1.0, 0.07)

    async def stop(self) -> None:
        self.w.log.append("gripper.stop")


class FakeForce:
    def __init__(self, world: FakeWorld) -> None:
        self.w = world

    def latest(self) -> ForceReading | None:
        return ForceReading(0.0, 3.0 if self.w.held else 0.0, 0, 0)

    def holding(self) -> bool:
        return self.w.held is not None


class FakeObserver:
    def __init__(self, world: FakeWorld) -> None:
        self.w = world

    async def observe(self) -> Observation:
        await asyncio.sleep(0)
        seen = [d for k, d in self.w.counter.items() if k != self.w.held]
        # The placed mugs where they were set down (the job knows them: its own work); a mug placed by no
        # planned cycle, in rows of three on the tray.
        seen += [
            Detection(
                "big", *self.w.placed_at.get(k, (0.3 + 0.1 * (i % 3), -0.15 + 0.1 * (i // 3))), True, 0.0, 0.9
            )
            for i, k in enumerate(self.w.placed)
        ]
        return Observation(0.0, tuple(Detection(d.type, d.x_m, d.y_m, False, 0.0, 0.9) for d in seen))


class FakeMotion:
    """A motion planner test double (a whole ``planning.interfaces.MotionPlanner``): one short joint move per
    manipulation phase, a CLOSE at each close phase, an OPEN at each release phase. ``refuse`` lists the
    (true) mugs it cannot reach; ``blocked_by`` maps a mug to the counter mug that blocks it while that one
    is still there. ``plan_for_slot`` fills a slot as ``CyclePlanner.plan_for_slot`` does: the mug it names,
    else another of its type, nearest the arm first (a lone candidate's refusal is passed on as it is).
    ``calls`` lists the planning requests."""

    def __init__(self, world: FakeWorld, refuse: Sequence[str] = ()) -> None:
        self.w = world
        self.refuse = set(refuse)
        self.bridges: list[str] = []
        self.obstacles: list[tuple[str, ...]] = []
        self.on_tray_seen: list[tuple[TraySlot, ...]] = []
        self.blocked_by: dict[str, str] = {}  # mug -> the counter mug that blocks it while still there
        self.calls: list[str] = []  # "cycle:<id>" or "slot:<id>" per request

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        self.calls.append(f"slot:{slot.mug_id}")
        named = [m for m in counter if m.mug_id == slot.mug_id]
        others = sorted(
            (m for m in counter if m.type == slot.type and m.mug_id != slot.mug_id),
            key=lambda m: (math.hypot(m.x_m, m.y_m), m.mug_id),
        )
        refusals = []
        for mug in [*named, *others]:
            try:
                cycle = self._cycle(start_q, mug, on_tray, counter)
            except MotionRefused as e:
                refusals.append(e)
                continue
            self.w.slot_for[self.w.target or ""] = (slot.x_m, slot.y_m)
            return mug, cycle
        if len(refusals) == 1:
            raise refusals[0]
        why = "; ".join(map(str, refusals))
        raise MotionRefused.combining(
            f"slot for {slot.mug_id}: no {slot.type} mug can be moved there ({why})", refusals
        )

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        self.calls.append(f"cycle:{mug.mug_id}")
        cycle = self._cycle(start_q, mug, on_tray, [*counter, mug])
        self.w.slot_for[self.w.target or ""] = (slot.x_m, slot.y_m)
        return cycle

    def _cycle(
        self, start_q: Sequence[float], mug: MugPose, on_tray: Sequence[TraySlot], counter: Sequence[MugPose]
    ) -> CyclePlan:
        """``mug``'s cycle; ``counter`` holds every mug on the counter (``mug`` too)."""
        others = [m for m in counter if m.mug_id != mug.mug_id]
        self.obstacles.append(tuple(m.mug_id for m in others))
        self.on_tray_seen.append(tuple(on_tray))
        true_id = self._true(mug)
        if true_id in self.refuse:
            raise MotionRefused(f"{mug.mug_id} at ({mug.x_m:.3f}, {mug.y_m:.3f}) is out of reach")
        blocker = self.blocked_by.get(true_id)
        in_front = [m.mug_id for m in others if self._true(m) == blocker] if blocker in self.w.counter else []
        if in_front:  # blocked only by an obstacle it was given, as the cycle planner is
            raise MotionRefused(
                f"{mug.mug_id}: the gripper would hit the mug in front of it", blockers=in_front
            )
        self.w.target = true_id
        steps = []
        q = np.asarray(start_q, dtype=np.float64)
        for k, phase in enumerate(CYCLE_PHASES):
            leaf = phase.split(".")[1]
            if leaf == "close":
                steps.append(Step(phase, StepKind.CLOSE))
            elif leaf == "release":
                steps.append(Step(phase, StepKind.OPEN))
            elif leaf != "verify":
                goal = np.full(5, 0.1 * (k % 7))
                steps.append(Step(phase, StepKind.MOVE, self._line(q, goal, label=f"{phase}:{mug.mug_id}")))
                q = goal
        # A predicted handle yaw per plan (0.1 rad per mug already on the tray), to follow through the job.
        handle = 0.1 * len(on_tray)
        return CyclePlan(mug.mug_id, tuple(steps), duration_s=1.0, energy_j=1.0, handle_yaw_rad=handle)

    def _true(self, mug: MugPose) -> str:
        """The world's mug nearest where the job thinks ``mug`` is."""
        c = self.w.counter
        return min(c, key=lambda k: math.hypot(c[k].x_m - mug.x_m, c[k].y_m - mug.y_m))

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        self.bridges.append(label)
        return self._line(np.asarray(start_q), np.asarray(goal_q), label=label)

    @staticmethod
    def _line(a: np.ndarray, b: np.ndarray, *, label: str) -> JointTrajectory:
        s = np.linspace(0.0, 1.0, 20)
        return JointTrajectory(NAMES, s * 0.1, a + np.outer(s, b - a), label=label)


def make_world(n: int = 3) -> FakeWorld:
    counter = {
        f"true{i}": Detection("big" if i % 2 else "small", -0.1 * i, 0.3 + 0.01 * i, False, 0.0, 1.0)
        for i in range(n)
    }
    return FakeWorld(counter=counter)


def make_backend(
    world: FakeWorld, *, refuse: Sequence[str] = (), clock: SessionClock | None = None
) -> Backend:
    """The stand-ins as a backend, on ``clock`` (default the wall clock)."""
    return Backend(
        name="fake",
        arm=FakeArm(world),
        gripper=FakeGripper(world),
        force=FakeForce(world),
        observer=FakeObserver(world),
        motion=FakeMotion(world, refuse),
        tray=Tray(
            origin_m=(0.25, -0.187), size_mm=(332, 374)
        ),  # the observer also sees the placed mugs there
        clock=clock or RealClock(),
    )
