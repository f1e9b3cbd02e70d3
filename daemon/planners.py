"""The motion planner a backend runs: the cycle planner of the configured cell, in this process or in a
process pool (``ProcessMotionPlanner``, so planning does not stall the event loop), placement planning for
the pool, and ``MotionCalls``, a planner in front of another (the recording's, the replay's).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

from daemon.config import Config
from daemon.errors import UsageError
from description.cell import CellLayout, Tray
from description.thesis import MugSpec, mug_catalogue
from drivers.interfaces import (
    JointTrajectory,
)
from planning.arm import ArmModel
from planning.arm.calibration import PositionCorrection
from planning.interfaces import CyclePlan, MotionPlanner, MugPose, TraySlot
from planning.motion import DynamicsMoveCost, check_reachable
from planning.motion.planner import CyclePlanner
from planning.motion.scene import SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S
from planning.placement import PlanOptions, PlanResult, Problem, plan
from wire.messages import MotionCall

T = TypeVar("T")


class MotionCalls:
    """A motion planner in front of another (``inner``): each of its three calls, with the arguments that
    name it, goes through ``_call(call, args, run)``, where ``run()`` asks the inner planner (the recorder
    records them, a replay serves recorded plans)."""

    inner: MotionPlanner

    def _call(self, call: MotionCall, args: tuple[object, ...], run: Callable[[], T]) -> T:
        raise NotImplementedError

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        return self._call(
            "plan_cycle",
            (tuple(start_q), mug, slot, tuple(on_tray), tuple(counter)),
            lambda: self.inner.plan_cycle(start_q, mug, slot, on_tray, counter=counter),
        )

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        return self._call(
            "plan_for_slot",
            (tuple(start_q), slot, tuple(counter), tuple(on_tray)),
            lambda: self.inner.plan_for_slot(start_q, slot, counter, on_tray),
        )

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        return self._call(
            "plan_move",
            (tuple(start_q), tuple(goal_q), label),
            lambda: self.inner.plan_move(start_q, goal_q, label=label),
        )


def load_correction(config: Config) -> PositionCorrection | None:
    """The arm's position correction named by ``arm.calibration_file``; a bad file is a usage error."""
    path = config.arm.calibration_file
    if path is None:
        return None
    try:
        return PositionCorrection.load(path)
    except ValueError as e:  # CalibrationError
        raise UsageError(f"arm.calibration_file: {e}") from e


def check_cell_reachable(config: Config, arm: ArmModel) -> None:
    """Refuse a configured cell the arm cannot serve: every counter, flip-area and tray corner must be
    reachable with every mug type of the catalogue (``planning.motion.check_reachable``)."""
    problems = check_reachable(config.cell, arm, config.mug_catalogue())
    if problems:
        raise UsageError(f"the arm cannot serve the configured cell: {'; '.join(problems)}")


@dataclass(frozen=True, slots=True)
class CyclePlannerSpec:
    """Everything needed to build the cycle planner, hashable and picklable, so that a planning process can
    build it once and reuse it: the cell, the tray the job fills (the cell's, or the one a simulated counter
    was set up with), the mug catalogue and the arm's position correction (``arm.calibration_file``)."""

    cell: CellLayout
    tray: Tray
    mug_types: tuple[MugSpec, ...]
    correction: PositionCorrection | None = None
    set_down: tuple[float, float] = (SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S)  # ``arm.set_down_*``

    def layout(self) -> CellLayout:
        return self.cell.with_tray(self.tray)

    def catalogue(self) -> dict[str, MugSpec]:
        return mug_catalogue(self.mug_types)

    def build(self, arm: ArmModel | None = None) -> CyclePlanner:
        slow_m, speed_m_s = self.set_down
        return CyclePlanner(
            arm or ArmModel.load(),
            self.layout(),
            self.catalogue(),
            correction=self.correction,
            set_down_slow_m=slow_m,
            set_down_speed_m_s=speed_m_s,
        )

    def move_cost(self) -> DynamicsMoveCost:
        """The placement move cost from the arm's dynamics (``planner.energy_model = "dynamics"``)."""
        return DynamicsMoveCost(ArmModel.load(), self.layout(), self.catalogue(), set_down=self.set_down)


@functools.lru_cache(maxsize=4)
def _planner_in_this_process(spec: CyclePlannerSpec) -> CyclePlanner:
    return spec.build()


@functools.lru_cache(maxsize=4)
def _move_cost_in_this_process(spec: CyclePlannerSpec) -> DynamicsMoveCost:
    return spec.move_cost()


def plan_placement(problem: Problem, options: PlanOptions, dynamics: CyclePlannerSpec | None) -> PlanResult:
    """Placement planning; with ``dynamics``, move costs come from the arm's dynamics in that cell (built once
    per process: it plans reference cycles). Module-level, so a process pool can run it."""
    if dynamics is not None:
        options = dataclasses.replace(options, move_cost=_move_cost_in_this_process(dynamics))
    return plan(problem, options)


def _build_in_this_process(spec: CyclePlannerSpec) -> None:
    _planner_in_this_process(spec)


def _plan_cycle(
    spec: CyclePlannerSpec,
    start_q: tuple[float, ...],
    mug: MugPose,
    slot: TraySlot,
    on_tray: tuple[TraySlot, ...],
    counter: tuple[MugPose, ...],
) -> CyclePlan:
    return _planner_in_this_process(spec).plan_cycle(start_q, mug, slot, on_tray, counter=counter)


def _plan_for_slot(
    spec: CyclePlannerSpec,
    start_q: tuple[float, ...],
    slot: TraySlot,
    counter: tuple[MugPose, ...],
    on_tray: tuple[TraySlot, ...],
) -> tuple[MugPose, CyclePlan]:
    return _planner_in_this_process(spec).plan_for_slot(start_q, slot, counter, on_tray)


def _plan_move(
    spec: CyclePlannerSpec, start_q: tuple[float, ...], goal_q: tuple[float, ...], label: str
) -> JointTrajectory:
    return _planner_in_this_process(spec).plan_move(start_q, goal_q, label=label)


class ProcessMotionPlanner:
    """A ``MotionPlanner`` whose planning runs in another process (``executor``, a process pool).

    Planning is CPU-bound Python and C++ that holds the GIL; in the daemon's process it would stall the event
    loop (telemetry, commands) for tens of milliseconds at a time. Calls block until the result is back, so
    the job calls them from a thread (``asyncio.to_thread``), as it does any planner."""

    def __init__(self, spec: CyclePlannerSpec, executor: concurrent.futures.Executor) -> None:
        self._spec = spec
        self._executor = executor

    def warm_up(self) -> concurrent.futures.Future[None]:
        """Build the planner in the worker now (model loading takes a while), not on the first mug."""
        return self._executor.submit(_build_in_this_process, self._spec)

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        future = self._executor.submit(
            _plan_cycle, self._spec, tuple(start_q), mug, slot, tuple(on_tray), tuple(counter)
        )
        return future.result()

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        future = self._executor.submit(
            _plan_for_slot, self._spec, tuple(start_q), slot, tuple(counter), tuple(on_tray)
        )
        return future.result()

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        return self._executor.submit(_plan_move, self._spec, tuple(start_q), tuple(goal_q), label).result()


def set_down(config: Config) -> tuple[float, float]:
    """How the cycle planner sets a held mug down (``arm.set_down_slow_m``, ``arm.set_down_speed_m_s``)."""
    return (config.arm.set_down_slow_m, config.arm.set_down_speed_m_s)


def cycle_planner(
    config: Config, tray: Tray, *, arm: ArmModel, executor: concurrent.futures.Executor | None
) -> MotionPlanner:
    """The cycle planner every backend runs on: the configured cell with ``tray``, the configured catalogue
    and the arm's position correction; in ``executor`` (a process pool) when one is given."""
    spec = CyclePlannerSpec(config.cell, tray, config.mug_types, load_correction(config), set_down(config))
    return spec.build(arm) if executor is None else ProcessMotionPlanner(spec, executor)
