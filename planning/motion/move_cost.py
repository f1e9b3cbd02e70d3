"""The placement planner's time and energy of one mug (``planning.placement.cost.MoveCost``) from the arm
model instead of the thesis's straight-line proxies (Eq 4.2, Eq 4.5).

The placement optimisers ask for thousands of (mug, spot) costs, too many to plan every cycle in full. The
cost is therefore split in two: the joint moves that depend on where the mug starts and ends (from above the
tray to above the mug, to the flip area, the turn, to above the spot) are timed within the servo limits and
costed with RNEA and the servo model, with poses cached on a 5 mm grid; everything else in a cycle (the fine
approach, lift, set-down, regrasp, descend and retreat moves and the gripper waits) is taken once per mug
type from a fully planned reference cycle, so the estimate equals the cycle planner's at the reference.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import structlog

from description import thesis
from description.cell import CellLayout
from description.thesis import MugSpec
from drivers.interfaces import FloatArray
from planning.arm.grasp import handle_facing_away_rad, lateral_offset_m, side_grasp
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import MotionRefused, MugPose, TraySlot
from planning.motion.energy import DynamicsEnergyModel
from planning.motion.planner import CyclePlanner
from planning.motion.scene import SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S
from planning.motion.trajectory import JointPath

log = structlog.get_logger(__name__)

# A spot the arm cannot serve costs what the thesis allows at most per mug, and ten reference cycles' energy:
# dear enough that no optimiser prefers it, finite so the run's normalisation (Eq 4.2-4.5) stays defined.
_PENALTY_ENERGY_FACTOR = 10.0


@dataclass(frozen=True, slots=True)
class _Overhead:
    seconds: float
    joules: float


class DynamicsMoveCost:
    """(seconds, joules) to carry one mug from the counter to a tray spot, from the arm's dynamics."""

    def __init__(
        self,
        arm: ArmModel,
        cell: CellLayout,
        catalogue: Mapping[str, MugSpec] | None = None,
        *,
        rate_hz: float = 25.0,
        set_down: tuple[float, float] = (SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S),
    ) -> None:
        # Its own copy of the model: the placement planner may run beside the cycle planner.
        arm = arm.copy()
        self.arm = arm
        self.cell = cell
        self.catalogue = dict(catalogue or thesis.MUG_TYPES)
        self.rate_hz = rate_hz
        slow_m, speed_m_s = set_down  # the cycle planner's set_down_slow_m and set_down_speed_m_s
        self._planner = CyclePlanner(
            arm, cell, self.catalogue, set_down_slow_m=slow_m, set_down_speed_m_s=speed_m_s
        )
        self._energy: DynamicsEnergyModel = self._planner.energy_model
        self._poses: dict[tuple[int, int, str, str], FloatArray | None] = {}
        self._overhead = {name: self._reference(spec) for name, spec in self.catalogue.items()}

    def __call__(
        self, mug_mass_kg: float, start_xy_m: tuple[float, float], goal_xy_m: tuple[float, float]
    ) -> tuple[float, float]:
        spec = min(self.catalogue.values(), key=lambda m: abs(m.mass_kg - mug_mass_kg))
        overhead = self._overhead[spec.name]
        moves = self._moves(spec, mug_mass_kg, start_xy_m, goal_xy_m)
        if moves is None:
            return thesis.MAX_SECONDS_PER_MUG, _PENALTY_ENERGY_FACTOR * max(overhead.joules, 1.0)
        seconds, joules = moves
        return seconds + overhead.seconds, joules + overhead.joules

    def _moves(
        self, spec: MugSpec, mass: float, start_xy: tuple[float, float], goal_xy: tuple[float, float]
    ) -> tuple[float, float] | None:
        """Time and energy (standby included) of the position-dependent moves; None if unreachable."""
        home = self._pose(self._tray_centre(), spec, GraspKind.SIDE_UPSIDE_DOWN)
        pick = self._pose(start_xy, spec, GraspKind.SIDE)
        flip_up = self._pose(self.cell.flip_area_center_m, spec, GraspKind.SIDE, flip=True)
        flip_down = self._pose(self.cell.flip_area_center_m, spec, GraspKind.SIDE_UPSIDE_DOWN, flip=True)
        place = self._pose(goal_xy, spec, GraspKind.SIDE_UPSIDE_DOWN)
        if home is None or pick is None or flip_up is None or flip_down is None or place is None:
            return None
        lateral = lateral_offset_m(spec, self.arm.gripper)
        seconds = joules = 0.0
        for a, b, payload in (
            (home, pick, 0.0),
            (pick, flip_up, mass),
            (flip_up, flip_down, mass),
            (flip_down, place, mass),
        ):
            path = JointPath(np.array([a, b]), self.arm.max_velocity, self.arm.max_acceleration)
            seconds += path.duration
            joules += self._energy.path_energy(
                path, self.rate_hz, payload_kg=payload, payload_lateral_m=lateral
            ).total_j
        return seconds, joules + self._energy.idle_energy_j(seconds)

    def _reference(self, spec: MugSpec) -> _Overhead:
        """Plan one full cycle (mug mid-counter to mid-tray) and keep what the key moves do not explain."""
        x0, y0, x1, y1 = self.cell.counter_region_m
        start = ((x0 + x1) / 2, (y0 + y1) / 2)
        goal = self._tray_centre()
        home = self._pose(goal, spec, GraspKind.SIDE_UPSIDE_DOWN)
        moves = self._moves(spec, spec.mass_kg, start, goal)
        if home is None or moves is None:
            return _Overhead(0.0, 0.0)
        mug = MugPose("reference", spec.name, *start, handle_yaw_rad=handle_facing_away_rad(*start))
        slot = TraySlot("reference", spec.name, *goal)
        try:
            cycle = self._planner.plan_cycle(tuple(float(v) for v in home), mug, slot, [])
        except MotionRefused as e:
            log.warning("move_cost_reference_refused", mug_type=spec.name, reason=str(e))
            return _Overhead(0.0, 0.0)
        return _Overhead(max(0.0, cycle.duration_s - moves[0]), max(0.0, cycle.energy_j - moves[1]))

    def _tray_centre(self) -> tuple[float, float]:
        x0, y0, x1, y1 = self.cell.tray.region_m
        return (x0 + x1) / 2, (y0 + y1) / 2

    def _pose(
        self, xy: tuple[float, float], spec: MugSpec, kind: GraspKind, *, flip: bool = False
    ) -> FloatArray | None:
        """Joint angles holding a mug at ``xy`` at carry height (cached on a 5 mm grid). ``flip``: the
        turning pose above the flip area, whose grasp point is the set-down grasp's."""
        key = (round(xy[0] * 200), round(xy[1] * 200), spec.name, f"{kind}{flip}")
        if key in self._poses:
            return self._poses[key]
        carry = self._planner.carry_z_m
        pose: FloatArray | None = None
        try:
            if flip:
                g = side_grasp(
                    xy[0], xy[1], spec, self.arm.gripper, z_m=carry, kind=GraspKind.SIDE_UPSIDE_DOWN
                )
                target = GraspTarget(g.target.position_m, kind)
            else:
                target = side_grasp(xy[0], xy[1], spec, self.arm.gripper, z_m=carry, kind=kind).target
        except ValueError:
            target = None
        if target is not None:
            result = self.arm.ik(target)
            if result.ok and result.q is not None and all(math.isfinite(v) for v in result.q):
                pose = np.asarray(result.q)
        self._poses[key] = pose
        return pose
