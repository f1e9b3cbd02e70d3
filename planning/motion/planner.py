"""The pick-flip-place cycle of one mug (thesis §4.3, Figure 4.18) as checked joint trajectories.

Per mug: approach the counter mug from behind at grasp height and side-grasp it, lift to carry height,
carry it along an arc at constant height to above the flip area, turn the wrist by pi, set the mug down
upside down, let go, back off and regrasp it from the side 6 cm above the counter, lift, carry it to above
its tray slot, descend until its brim is just above the tray, let go and back off. Every motion is sampled at
the control rate within the servo limits and checked for collisions before the plan is returned; anything
unreachable, out of limits, non-finite or colliding raises ``MotionRefused`` and nothing is commanded.
"""

from __future__ import annotations

import math
import re
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import structlog

from description import thesis
from description.arm import JOINT_LIMITS
from description.cell import CellLayout
from description.thesis import MugSpec
from drivers.interfaces import FloatArray, JointTrajectory
from planning.arm.calibration import PositionCorrection
from planning.arm.grasp import lateral_offset_m, reach_past_axis_m, side_grasp
from planning.arm.model import ArmModel, JointValues
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import CyclePlan, MotionRefused, MugPose, Step, StepKind, TraySlot
from planning.motion.cell import carry_height_m
from planning.motion.collision import (
    BASE_COLUMN,
    Box,
    CollisionWorld,
    Cylinder,
    HeldMug,
    mug_obstacles,
    tray_walls,
)
from planning.motion.energy import DynamicsEnergyModel
from planning.motion.trajectory import JointPath, plan_path

log = structlog.get_logger(__name__)

_MAX_JOINT_STEP_RAD = 0.35
_POSE_SUFFIX = re.compile(r" \(pose \d+ of \d+\)$")


@dataclass(frozen=True, slots=True)
class _Motion:
    """One planned move with what the collision check and the energy model need."""

    step: Step
    path: JointPath
    payload_kg: float
    payload_lateral_m: float = 0.0


class CyclePlanner:
    """Plans pick-flip-place cycles of the arm in a cell; implements ``planning.interfaces.MotionPlanner``."""

    def __init__(
        self,
        arm: ArmModel,
        cell: CellLayout,
        catalogue: Mapping[str, MugSpec],
        *,
        control_rate_hz: float = 50.0,
        back_off_m: Sequence[float] = (0.06, 0.03, 0.0),
        side_clearance_m: float = 0.004,
        release_gap_m: float = 0.008,
        release_openings_m: Sequence[float] = (0.012, 0.006),
        fine_speed_m_s: float = 0.08,
        gripper_close_s: float = 1.0,
        gripper_open_s: float = 0.6,
        energy_model: DynamicsEnergyModel | None = None,
        correction: PositionCorrection | None = None,
    ) -> None:
        if not control_rate_hz > 0:
            raise ValueError(f"control_rate_hz must be > 0, got {control_rate_hz}")
        if not catalogue:
            raise ValueError("catalogue must hold at least one mug type")
        self.arm = arm
        self.cell = cell
        self.catalogue = dict(catalogue)
        self.control_rate_hz = control_rate_hz
        self.back_off_m = tuple(back_off_m)
        self.side_clearance_m = side_clearance_m
        self.release_gap_m = release_gap_m
        self.release_openings_m = tuple(release_openings_m)
        self.fine_speed_m_s = fine_speed_m_s
        self.gripper_close_s = gripper_close_s
        self.gripper_open_s = gripper_open_s
        self.energy_model = energy_model or DynamicsEnergyModel(arm)
        self.correction = correction
        # The arm model keeps one Pinocchio Data: calls from several threads take turns.
        self._lock = threading.Lock()
        # What every candidate for a slot shares (``_shared_refusals``), by slot and the mugs on the tray.
        self._shared: dict[
            tuple[TraySlot, tuple[TraySlot, ...]], tuple[MotionRefused | None, MotionRefused | None] | None
        ] = {}
        tallest = max(m.height_mm for m in self.catalogue.values()) / 1000.0
        # Mugs on the tray stand on its base, so the tallest obstacle is that much higher there.
        self.carry_z_m = carry_height_m(tallest + max(0.0, cell.tray.base_m))
        self.open_aperture_m = arm.gripper.aperture_m(JOINT_LIMITS["gripper"].lower_rad)

    def __getstate__(self) -> dict[str, object]:
        """Picklable (the daemon may plan in a worker process): the lock and what it remembers stay behind."""
        state = dict(self.__dict__)
        del state["_lock"]
        state["_shared"] = {}
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def plan_move(
        self,
        start_q: Sequence[float],
        goal_q: Sequence[float],
        *,
        label: str,
        counter: Sequence[MugPose] = (),
        on_tray: Sequence[TraySlot] = (),
    ) -> JointTrajectory:
        """A joint-space move within the servo limits with nothing held (parking, recovery), refused when
        either end is invalid or the open gripper would hit the counter, base, tray or the mugs given."""
        start = self._checked_q(start_q, "start_q")
        goal = self._checked_q(goal_q, "goal_q")
        with self._lock:
            trajectory, _ = self._plan(np.array([start, goal]), label)
            world = self._world(counter, on_tray)
            hit = world.first_collision(trajectory.positions, aperture_m=self.open_aperture_m)
        if hit is not None:
            raise MotionRefused(f"{label}: {hit}", blockers=hit.mug_ids)
        return trajectory

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        """Every step to take ``mug`` from the counter to ``slot``; ``counter`` lists the other mugs still on
        the counter (obstacles), ``on_tray`` the mugs already placed."""
        start = self._checked_q(start_q, "start_q")
        spec = self._spec(mug.type, f"mug {mug.mug_id}")
        slot_spec = self._spec(slot.type, f"slot for {slot.mug_id}")
        if slot_spec != spec:
            raise MotionRefused(f"mug {mug.mug_id} is a {mug.type} mug but its slot is for a {slot.type} mug")
        if slot.rotated:
            raise MotionRefused(
                f"slot for {mug.mug_id} is rotated: the arm has no wrist yaw and cannot turn a mug about z"
            )
        for name, v in (
            ("mug.x_m", mug.x_m),
            ("mug.y_m", mug.y_m),
            ("slot.x_m", slot.x_m),
            ("slot.y_m", slot.y_m),
        ):
            if not math.isfinite(v):
                raise MotionRefused(f"mug {mug.mug_id}: {name} is not finite")
        self._check_slot_in_tray(slot, spec)
        with self._lock:
            motions = self._cycle_motions(start, mug, spec, slot, on_tray, counter)
            if not mug.handle_seen:
                # Nothing to predict from: the packing's assumption (handle along +x) stands.
                return self._costed(mug, motions)
            handle_yaw = self._handle_yaw_on_tray(mug, motions)
            self._check_handle(mug, slot, spec, handle_yaw, on_tray)
            return replace(self._costed(mug, motions), handle_yaw_rad=handle_yaw)

    def _handle_yaw_on_tray(self, mug: MugPose, motions: Sequence[_Motion]) -> float:
        """Where the mug's handle points once placed: the mug turns with the gripper between each grasp and
        its release, so its counter yaw is carried through pick -> set-down and regrasp -> place (a mug
        already upside down: pick -> place)."""

        def grasp_rotation(phase: str) -> FloatArray:
            last = [m for m in motions if m.step.phase == phase and m.step.trajectory is not None][-1]
            assert last.step.trajectory is not None
            return self.arm.fk(last.step.trajectory.positions[-1])[1]

        d = np.array([math.cos(mug.handle_yaw_rad), math.sin(mug.handle_yaw_rad), 0.0])
        turns = [("side_grasp.approach", "place.descend")]
        if not mug.upside_down:
            turns = [("side_grasp.approach", "flip.set_down"), ("flip.regrasp", "place.descend")]
        for grasped, released in turns:
            d = grasp_rotation(released) @ grasp_rotation(grasped).T @ d
        return math.atan2(float(d[1]), float(d[0]))

    def _check_handle(
        self, mug: MugPose, slot: TraySlot, spec: MugSpec, yaw: float, on_tray: Sequence[TraySlot]
    ) -> None:
        """Refuse a cycle that leaves the mug's handle in a placed mug or over the tray's wall: the packing
        plans with the handle along +x, and the arm cannot turn a mug about z. Seen from above a handle is a
        bar from the wall out to the mug's width, ``HANDLE_HALF_THICKNESS_M`` thick; it must keep
        ``HANDLE_CLEARANCE_M`` from every placed mug's body and handle."""
        mine = _handle_bar(slot.x_m, slot.y_m, spec, yaw)
        where = f"mug {mug.mug_id}'s handle would end at {math.degrees(yaw):.0f} deg"
        x0, y0, x1, y1 = self.cell.tray.region_m
        reach = HANDLE_HALF_THICKNESS_M
        (ax, ay), (bx, by) = mine
        if (
            min(ax, bx) - reach < x0
            or max(ax, bx) + reach > x1
            or min(ay, by) - reach < y0
            or max(ay, by) + reach > y1
        ):
            raise MotionRefused(f"place: {where}, over the tray's wall")
        body_r = spec.diameter_mm / 2000.0
        for s in on_tray:
            yaw_s = s.handle_yaw_rad if s.handle_yaw_rad is not None else (math.pi / 2 if s.rotated else 0.0)
            other = self._spec(s.type, f"mug {s.mug_id}")
            theirs = _handle_bar(s.x_m, s.y_m, other, yaw_s)
            gaps = (
                (_segment_point_m(mine, (s.x_m, s.y_m)) - other.diameter_mm / 2000.0 - reach, "body"),
                (_segment_point_m(theirs, (slot.x_m, slot.y_m)) - body_r - reach, "handle"),
                (_segment_segment_m(mine, theirs) - 2 * reach, "handle"),
            )
            for gap, part in gaps:
                if gap < HANDLE_CLEARANCE_M:
                    raise MotionRefused(
                        f"place: {where}, {max(gap, 0.0) * 1000:.0f} mm from the {part} of mug {s.mug_id}",
                        blockers=(s.mug_id,),
                    )

    def _costed(self, mug: MugPose, motions: Sequence[_Motion]) -> CyclePlan:
        """The plan of a cycle's motions with its predicted duration and electrical energy."""
        steps: list[Step] = []
        duration = 0.0
        energy = 0.0
        for m in motions:
            steps.append(m.step)
            if m.step.kind is StepKind.MOVE:
                duration += m.path.duration
                energy += self.energy_model.path_energy(
                    m.path,
                    self.control_rate_hz,
                    payload_kg=m.payload_kg,
                    payload_lateral_m=m.payload_lateral_m,
                ).total_j
            else:
                wait = self.gripper_close_s if m.step.kind is StepKind.CLOSE else self.gripper_open_s
                duration += wait
                energy += self.energy_model.hold_energy_j(m.path.waypoints[0], wait)
        energy += self.energy_model.idle_energy_j(duration)
        log.info("cycle_planned", mug_id=mug.mug_id, steps=len(steps), duration_s=round(duration, 2))
        return CyclePlan(mug_id=mug.mug_id, steps=tuple(steps), duration_s=duration, energy_j=energy)

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        """Plan the cycle for ``slot`` with the mug it names or, when that one cannot be reached (another mug
        stands in front of it, say), with another counter mug of the same type, nearest the arm first
        (thesis §4.1: the closest mug is taken). Returns the mug used and its plan; raises ``MotionRefused``
        listing why each candidate failed.

        What every candidate shares is decided first, once per slot and tray: whether a mug of the type
        can be put down in the slot, and (for a mug standing upright) turned over in the flip area, each
        from above it with the counter's mugs left out. When either is impossible, no candidate is tried:
        fewer obstacles and the same motions cannot make any of them possible."""
        named = [m for m in counter if m.mug_id == slot.mug_id]
        others = sorted(
            (m for m in counter if m.type == slot.type and m.mug_id != slot.mug_id),
            key=lambda m: (math.hypot(m.x_m, m.y_m), m.mug_id),
        )
        candidates = [*named, *others]
        reasons: list[tuple[str, MotionRefused]] = []
        shared = self._shared_refusals(slot, on_tray) if candidates else None
        if shared is not None:
            place, upright = shared
            if place is not None:
                raise MotionRefused.combining(
                    f"slot for {slot.mug_id}: no {slot.type} mug can be moved there ({place})", [place]
                )
            if upright is not None:
                if not any(m.upside_down for m in candidates):
                    raise MotionRefused.combining(
                        f"slot for {slot.mug_id}: no {slot.type} mug can be moved there "
                        f"(a mug standing upright: {upright})",
                        [upright],
                    )
                reasons.append(("every upright mug", upright))
                candidates = [m for m in candidates if m.upside_down]
        for mug in candidates:
            try:
                plan = self.plan_cycle(
                    start_q, mug, replace(slot, mug_id=mug.mug_id), on_tray, counter=counter
                )
            except MotionRefused as e:
                reasons.append((mug.mug_id, e))
                continue
            return mug, plan
        if not reasons:
            raise MotionRefused(f"slot for {slot.mug_id}: no {slot.type} mug left on the counter")
        why = "; ".join(f"{mug_id}: {e}" for mug_id, e in reasons)
        raise MotionRefused.combining(
            f"slot for {slot.mug_id}: no {slot.type} mug can be moved there ({why})", (e for _, e in reasons)
        )

    def _shared_refusals(
        self, slot: TraySlot, on_tray: Sequence[TraySlot]
    ) -> tuple[MotionRefused | None, MotionRefused | None] | None:
        """Why no mug of the slot's type can be put down in it (None: it can), and why none standing
        upright can be flipped and then put down in it (None: one can); None when the slot itself is
        refused before any motion (each candidate says why). Remembered per slot and tray."""
        try:
            spec = self._spec(slot.type, f"slot for {slot.mug_id}")
            if slot.rotated or not (math.isfinite(slot.x_m) and math.isfinite(slot.y_m)):
                return None
            self._check_slot_in_tray(slot, spec)
        except MotionRefused:
            return None
        placed = tuple(on_tray)
        key = (slot, placed)
        if key not in self._shared:
            if len(self._shared) >= _REMEMBERED:
                self._shared.clear()
            with self._lock:
                self._shared[key] = self._shared_motions_refused(slot, spec, placed)
        return self._shared[key]

    def _shared_motions_refused(
        self, slot: TraySlot, spec: MugSpec, placed: Sequence[TraySlot]
    ) -> tuple[MotionRefused | None, MotionRefused | None]:
        """``_shared_refusals``, worked out: the place part of a cycle from above the slot, and the flip
        part from above the flip area, with either wrist roll, among the tray's mugs only. A roll that
        works for both ends the search (what a slot that can be filled costs)."""
        c = _CycleContext(self, MugPose(slot.mug_id, slot.type, slot.x_m, slot.y_m), spec, slot, placed, ())
        place_z = self.cell.tray.base_m + thesis.GRASP_HEIGHT_M + self.release_gap_m
        fx, fy = self.cell.flip_area_center_m
        set_down_z = spec.height_mm / 1000.0 - thesis.GRASP_HEIGHT_M + self.release_gap_m
        flipped: list[_Builder] = []

        def place(kind: GraspKind) -> MotionRefused | None:
            try:
                target = self._grasp(slot.x_m, slot.y_m, spec, kind, place_z, f"slot of {slot.mug_id}")
            except MotionRefused as e:
                return e
            try:
                self._place(_Builder(self, self._above(target)), c, kind)
            except MotionRefused as e:
                return e
            return None

        def regrasp(kind: GraspKind) -> MotionRefused | None:
            if not flipped:
                set_down = self._grasp(fx, fy, spec, GraspKind.SIDE_UPSIDE_DOWN, set_down_z, "flip set-down")
                flip = _Builder(self, self._above(GraspTarget(set_down.position_m, GraspKind.SIDE)))
                self._flip(flip, c)
                flipped.append(flip)
            try:
                self._regrasp(flipped[0].fork(), c, kind)
            except MotionRefused as e:
                return e
            return None

        placing: list[MotionRefused | None] = []
        upright: list[MotionRefused] = []
        try:
            for kind in _ROLLS:
                refused = place(kind)
                placing.append(refused)
                if refused is None:
                    try:
                        refused = regrasp(kind)
                    except MotionRefused as e:
                        return None, e  # the flip itself, before either roll
                    if refused is None:
                        return None, None
                upright.append(refused)
        except _Undecided:
            return None, None
        if all(e is not None for e in placing):
            return _either(*placing), None
        return None, _either(*upright)

    def _above(self, target: GraspTarget) -> FloatArray:
        """The joint angles at carry height above ``target`` with its orientation; ``_Undecided`` when
        they cannot be had from no seed (a candidate's own way there decides)."""
        above = _at_z(target, self.carry_z_m)
        if self.correction is not None:
            above = GraspTarget(self.correction.correct(above.position_m), above.kind)
        result = self.arm.ik(above)
        if not result.ok or result.q is None:
            raise _Undecided
        return np.asarray(result.q)

    def _cycle_motions(
        self,
        start: FloatArray,
        mug: MugPose,
        spec: MugSpec,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        counter: Sequence[MugPose],
    ) -> list[_Motion]:
        c = _CycleContext(self, mug, spec, slot, on_tray, counter)
        plan = _Builder(self, start)

        def pick_and_place(b: _Builder, kind: GraspKind) -> None:
            self._pick(b, c, kind)
            self._place(b, c, kind)

        def regrasp_and_place(b: _Builder, kind: GraspKind) -> None:
            self._regrasp(b, c, kind)
            self._place(b, c, kind)

        if mug.upside_down:
            # Already upside down: no flip; either wrist roll can take it and place it.
            return self._either_roll(plan, pick_and_place)
        self._pick(plan, c, GraspKind.SIDE)
        self._flip(plan, c)
        return self._either_roll(plan, regrasp_and_place)

    def _either_roll(self, plan: _Builder, moves: Callable[[_Builder, GraspKind], None]) -> list[_Motion]:
        """Finish the cycle holding the inverted mug with the wrist turned (finger on the mug's right, as
        the thesis did) or, when that collides, with the wrist level (finger on the left): between close
        neighbours on the tray the opening finger needs the free side."""
        reasons: list[tuple[str, MotionRefused]] = []
        for kind, roll in ((GraspKind.SIDE_UPSIDE_DOWN, "wrist turned"), (GraspKind.SIDE, "wrist level")):
            trial = plan.fork()
            try:
                moves(trial, kind)
            except MotionRefused as e:
                reasons.append((roll, e))
                continue
            plan.adopt(trial)
            return plan.motions
        (_, first), (roll, second) = reasons
        why = str(first) if str(first) == str(second) else f"{first}; with the {roll}: {second}"
        raise MotionRefused.combining(why, (first, second))

    def _pick(self, plan: _Builder, c: _CycleContext, kind: GraspKind) -> None:
        """side_grasp: from above and behind the mug down to grasp height, in, close, up."""
        pick = self._grasp(
            c.mug.x_m, c.mug.y_m, c.spec, kind, thesis.GRASP_HEIGHT_M, f"grasp of mug {c.mug.mug_id}"
        )
        world = self._world(c.others, c.placed, target=c.mug, target_spec=c.spec)
        self._first_move(plan, pick, world, c.mug.mug_id)
        self._close_and_lift(plan, c, kind, "side_grasp", pick)

    def _close_and_lift(
        self, plan: _Builder, c: _CycleContext, kind: GraspKind, state: str, grasp: GraspTarget
    ) -> None:
        """``<state>.close`` on the mug at ``grasp``, then ``<state>.lift`` it straight up to carry height."""
        plan.gripper(f"{state}.close", StepKind.CLOSE)
        plan.line(
            f"{state}.lift",
            _at_z(grasp, self.carry_z_m),
            c.lift_world,
            aperture=c.holding,
            held=c.held(kind),
            mass=c.mass,
        )

    def _flip(self, plan: _Builder, c: _CycleContext) -> None:
        """flip: carry to above the flip area, turn the wrist by pi, set the mug down upside down, let go."""
        fx, fy = self.cell.flip_area_center_m
        h = c.spec.height_mm / 1000.0
        set_down_z = h - thesis.GRASP_HEIGHT_M + self.release_gap_m
        set_down = self._grasp(fx, fy, c.spec, GraspKind.SIDE_UPSIDE_DOWN, set_down_z, "flip set-down")
        above = GraspTarget(_xy_at(set_down, self.carry_z_m), GraspKind.SIDE)
        held = c.held(GraspKind.SIDE)  # the mug stays where it is in the gripper while the wrist turns
        plan.arc("flip.transit", above, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        turned = GraspTarget(above.position_m, GraspKind.SIDE_UPSIDE_DOWN)
        plan.joint_move("flip.turn", turned, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        plan.line("flip.set_down", set_down, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        plan.gripper("flip.release", StepKind.OPEN)
        c.set_down = set_down

    def _regrasp(self, plan: _Builder, c: _CycleContext, kind: GraspKind) -> None:
        """flip.regrasp .. flip.lift: back off the inverted mug, go to grasp height (turning the wrist if
        the other roll is wanted), go in, close, lift."""
        assert c.set_down is not None
        set_down = c.set_down
        fx, fy = self.cell.flip_area_center_m
        opened = self.open_aperture_m
        regrasp = self._grasp(fx, fy, c.spec, kind, thesis.GRASP_HEIGHT_M, "flip regrasp")
        flipped = MugPose(c.mug.mug_id, c.mug.type, fx, fy, upside_down=True)
        world = self._world(c.others, c.placed, target=flipped, target_spec=c.spec)

        def moves(b: _Builder, back: float, side: float) -> None:
            off = self._back_off(b, "flip.regrasp", set_down, back, side, world, opened, c.mug.mug_id)
            pre = self._clear_of(regrasp, back, side)
            if kind is not set_down.kind:
                # Rolling the wrist sweeps the palm round the approach axis: do it up at carry height.
                carry = self.carry_z_m
                b.line("flip.regrasp", _at_z(off, carry), world, aperture=opened)
                b.joint_move("flip.regrasp", _at_z(pre, carry), world, aperture=opened)
            b.line("flip.regrasp", pre, world, aperture=opened)
            beside = self._clear_of(regrasp, 0.0, side)
            b.line("flip.regrasp", beside, world, aperture=opened, ignore=c.mug.mug_id)
            b.line("flip.regrasp", regrasp, world, aperture=opened, ignore=c.mug.mug_id)

        self._try_offsets(plan, "flip.regrasp", moves)
        self._close_and_lift(plan, c, kind, "flip", regrasp)

    def _place(self, plan: _Builder, c: _CycleContext, kind: GraspKind) -> None:
        """place: carry to above the slot, descend until the brim is just above the tray, let go, back off."""
        tray_z = self.cell.tray.base_m
        place_z = tray_z + thesis.GRASP_HEIGHT_M + self.release_gap_m
        place = self._grasp(c.slot.x_m, c.slot.y_m, c.spec, kind, place_z, f"slot of {c.mug.mug_id}")
        held = c.held(kind)
        carry = self.carry_z_m
        plan.arc(
            "place.transit", _at_z(place, carry), c.lift_world, aperture=c.holding, held=held, mass=c.mass
        )
        plan.line("place.descend", place, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        placed_now = MugPose(c.mug.mug_id, c.mug.type, c.slot.x_m, c.slot.y_m, upside_down=True)
        done_world = self._world(
            c.others, c.placed, target=placed_now, target_spec=c.spec, target_floor=tray_z
        )
        reasons: list[MotionRefused] = []
        # Let go opening the jaw just wider than the mug (a full opening swings the finger into a neighbour
        # 1 cm away, the packing tolerance), the thumb stepping off the brim by half that; back off, and
        # open fully once up at carry height. The side step matters more than the width (backing straight
        # off dragged a mug 17 mm), so every opening with it is tried before any without; a full opening at
        # once is the last resort.
        partial = [(c.holding + extra, extra / 2) for extra in self.release_openings_m]
        releases: list[tuple[float | None, tuple[float, ...]]] = [(a, (side,)) for a, side in partial]
        releases += [(a, (0.0,)) for a, _ in partial]
        releases.append((None, (self.side_clearance_m, 0.0)))
        for aperture, sides in releases:
            trial = plan.fork()
            trial.gripper("place.release", StepKind.OPEN, aperture)
            jaw = self.open_aperture_m if aperture is None else aperture

            def retreat(b: _Builder, back: float, side: float, jaw: float = jaw) -> None:
                clear = self._back_off(b, "place.retreat", place, back, side, done_world, jaw, c.mug.mug_id)
                b.line("place.retreat", _at_z(clear, carry), done_world, aperture=jaw)

            try:
                self._try_offsets(trial, "place.retreat", retreat, sides=sides)
                if aperture is not None:
                    hit = done_world.first_collision(trial.q[None, :], aperture_m=self.open_aperture_m)
                    if hit is not None:
                        raise MotionRefused(
                            f"place.retreat: opening fully at carry height: {hit}", blockers=hit.mug_ids
                        )
                    trial.gripper("place.retreat", StepKind.OPEN)
            except MotionRefused as e:
                reasons.append(e)
                continue
            plan.adopt(trial)
            return
        first, last = str(reasons[0]), str(reasons[-1])
        raise MotionRefused.combining(first if first == last else f"{first}; opening fully: {last}", reasons)

    def _back_off(
        self,
        plan: _Builder,
        phase: str,
        grasp: GraspTarget,
        back_m: float,
        side_m: float,
        world: CollisionWorld,
        aperture_m: float,
        mug_id: str,
    ) -> GraspTarget:
        """From an opened grasp on a standing mug to ``_clear_of(grasp, back_m, side_m)``: the thumb first
        steps sideways off the brim, then the gripper backs away along the approach. Backing off on the
        diagonal dragged the mug along by the thumb's friction (12-17 mm in the MuJoCo cell), into the next
        mug on the tray. Returns where it ends."""
        if side_m > 0.0:
            plan.line(phase, self._clear_of(grasp, 0.0, side_m), world, aperture=aperture_m, ignore=mug_id)
        clear = self._clear_of(grasp, back_m, side_m)
        plan.line(phase, clear, world, aperture=aperture_m, ignore=mug_id)
        return clear

    def _first_move(self, plan: _Builder, pick: GraspTarget, world: CollisionWorld, mug_id: str) -> None:
        """side_grasp.approach: to above the pre-grasp point at carry height, down, then in to the grasp.
        The pre-grasp point is behind the mug along the approach when that is reachable and clear, else
        closer, else right above the grasp (the open gripper straddles the mug on the way down)."""
        opened = self.open_aperture_m
        carry = self.carry_z_m
        phase = "side_grasp.approach"
        # Every approach assumes the jaw fully open: open it first (the driver never closes to get there;
        # at the start of a job it may still be where the last one left it, narrower than a big mug).
        # Opening around a mug the gripper still straddles (after a failed grasp) is fine.
        straddled = world.mugs_around(plan.q, aperture_m=opened)
        skip = frozenset(f"mug {m}" for m in straddled)
        hit = world.first_collision(plan.q[None, :], aperture_m=opened, ignore=skip)
        if hit is not None:
            raise MotionRefused(f"{phase}: opening the gripper where the arm is: {hit}", blockers=hit.mug_ids)
        plan.gripper(phase, StepKind.OPEN)

        def approach(b: _Builder, d: float, side: float) -> None:
            pre = self._clear_of(pick, d, side)
            above = _at_z(pre, max(carry, pre.position_m[2]))
            if straddled:
                # After a failed grasp the open gripper still straddles that mug: lift straight off it first.
                b.rise(phase, carry, world, aperture=opened, ignore=straddled)
            try:
                b.joint_move(phase, above, world, aperture=opened)
            except MotionRefused as direct:
                try:
                    b.rise(phase, carry, world, aperture=opened)
                    b.joint_move(phase, above, world, aperture=opened)
                except MotionRefused as e:
                    raise MotionRefused.combining(str(e), (direct, e)) from e
            b.line(phase, pre, world, aperture=opened)
            # In beside the mug, then the thumb sideways onto the brim: closing in on the diagonal pushes
            # the mug along (10 mm measured on a big mug), off the grasp the rest of the cycle assumes.
            b.line(phase, self._clear_of(pick, 0.0, side), world, aperture=opened, ignore=mug_id)
            b.line(phase, pick, world, aperture=opened, ignore=mug_id)

        self._try_offsets(plan, phase, approach)

    def _try_offsets(
        self,
        plan: _Builder,
        phase: str,
        moves: Callable[[_Builder, float, float], object],
        *,
        sides: Sequence[float] | None = None,
    ) -> None:
        """Plan ``moves`` with the open gripper backed off by each of ``back_off_m`` in turn, first with the
        thumb ``side_clearance_m`` (or each of ``sides``) off the brim, then touching it (tight between
        neighbours); keep the first that works, or refuse with every reason."""
        reasons: list[MotionRefused] = []
        for back in self.back_off_m:
            for side in (self.side_clearance_m, 0.0) if sides is None else sides:
                trial = plan.fork()
                try:
                    moves(trial, back, side)
                except MotionRefused as e:
                    reasons.append(e)
                    continue
                plan.adopt(trial)
                return
        first, last = (str(reasons[i]).removeprefix(f"{phase}: ") for i in (0, -1))
        if _POSE_SUFFIX.sub("", first) == _POSE_SUFFIX.sub("", last):
            raise MotionRefused.combining(f"{phase}: {first}", reasons)
        raise MotionRefused.combining(f"{phase}: {first}; straight from above: {last}", reasons)

    def _plan(
        self, waypoints: FloatArray, label: str, *, tool_length_m: float = 0.0, fine: bool = False
    ) -> tuple[JointTrajectory, JointPath]:
        return plan_path(
            waypoints,
            names=self.arm.joint_names,
            max_velocity=self.arm.max_velocity,
            max_acceleration=self.arm.max_acceleration,
            rate_hz=self.control_rate_hz,
            label=label,
            tool_path_length_m=tool_length_m,
            max_tool_speed_m_s=self.fine_speed_m_s if fine else math.inf,
        )

    def _grasp(self, x: float, y: float, spec: MugSpec, kind: GraspKind, z: float, what: str) -> GraspTarget:
        try:
            return side_grasp(x, y, spec, self.arm.gripper, z_m=z, kind=kind).target
        except ValueError as e:
            raise MotionRefused(f"{what}: {e}") from e

    def _clear_of(self, target: GraspTarget, back_m: float, side_m: float) -> GraspTarget:
        """Where the open gripper is clear of the mug of a grasp: ``back_m`` back along the approach and
        ``side_m`` away from the mug on the thumb's side (the thumb touches the brim at the grasp)."""
        rotation = target.rotation()
        assert rotation is not None
        approach, mug_side = rotation[:, 2], rotation[:, 1]
        shift = -back_m * approach - side_m * mug_side
        x, y, z = target.position_m
        return GraspTarget((x + float(shift[0]), y + float(shift[1]), z), target.kind)

    def _spec(self, type_name: str, what: str) -> MugSpec:
        try:
            return self.catalogue[type_name]
        except KeyError as e:
            raise MotionRefused(
                f"{what}: unknown mug type {type_name!r} (catalogue: {', '.join(sorted(self.catalogue))})"
            ) from e

    def _checked_q(self, q: Sequence[float], name: str) -> FloatArray:
        arr = np.asarray(q, dtype=np.float64).reshape(-1)
        if arr.shape != (self.arm.dof,):
            raise MotionRefused(f"{name}: expected {self.arm.dof} joint angles, got {arr.size}")
        if not np.all(np.isfinite(arr)):
            raise MotionRefused(f"{name}: joint angles must be finite, got {[float(v) for v in arr]}")
        violations = self.arm.limit_violations(arr, tol=1e-6)
        if violations:
            raise MotionRefused(f"{name}: {'; '.join(violations)}")
        return arr

    def _check_slot_in_tray(self, slot: TraySlot, spec: MugSpec) -> None:
        x0, y0, x1, y1 = self.cell.tray.region_m
        r = spec.diameter_mm / 2000.0
        handle = spec.width_mm / 1000.0 - r
        if not (
            x0 + r <= slot.x_m + 1e-9
            and slot.x_m + handle <= x1 + 1e-9
            and y0 + r <= slot.y_m + 1e-9 <= y1 - r + 2e-9
        ):
            raise MotionRefused(
                f"slot of {slot.mug_id} at ({slot.x_m:.3f}, {slot.y_m:.3f}) m puts the mug outside the tray "
                f"[{x0:.3f}, {x1:.3f}] x [{y0:.3f}, {y1:.3f}]"
            )

    def _world(
        self,
        counter: Sequence[MugPose],
        placed: Sequence[TraySlot],
        *,
        target: MugPose | None = None,
        target_spec: MugSpec | None = None,
        target_floor: float = 0.0,
    ) -> CollisionWorld:
        cylinders: list[Cylinder] = [BASE_COLUMN]
        for m in counter:
            cylinders += mug_obstacles(
                f"mug {m.mug_id}",
                m.x_m,
                m.y_m,
                self._spec(m.type, f"mug {m.mug_id}"),
                handle_yaw_rad=m.handle_yaw_rad,
            )
        for s in placed:
            yaw = s.handle_yaw_rad if s.handle_yaw_rad is not None else (math.pi / 2 if s.rotated else 0.0)
            spec = self._spec(s.type, f"mug {s.mug_id}")
            floor = self.cell.tray.base_m
            cylinders += mug_obstacles(
                f"mug {s.mug_id}", s.x_m, s.y_m, spec, handle_yaw_rad=yaw, floor_z=floor
            )
        if target is not None and target_spec is not None:
            cylinders += mug_obstacles(
                f"mug {target.mug_id}",
                target.x_m,
                target.y_m,
                target_spec,
                handle_yaw_rad=target.handle_yaw_rad,
                floor_z=target_floor,
            )
        walls: list[Box] = tray_walls(
            self.cell.tray.region_m,
            height=self.cell.tray.wall_height_m,
            thickness=self.cell.tray.wall_thickness_m,
        )
        return CollisionWorld(self.arm, cylinders, walls)


class _CycleContext:
    """What every part of one mug's cycle needs: the mug, its slot, the obstacles and how it is held."""

    def __init__(
        self,
        planner: CyclePlanner,
        mug: MugPose,
        spec: MugSpec,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        counter: Sequence[MugPose],
    ) -> None:
        self.mug = mug
        self.spec = spec
        self.slot = slot
        self.others = [m for m in counter if m.mug_id != mug.mug_id]
        self.placed = list(on_tray)
        self.mass = spec.mass_kg
        self.holding = spec.diameter_mm / 1000.0
        self.lift_world = planner._world(self.others, self.placed)
        self.set_down: GraspTarget | None = None
        self._delta = lateral_offset_m(spec, planner.arm.gripper)
        self._reach = reach_past_axis_m(spec, planner.arm.gripper)

    def held(self, kind: GraspKind) -> HeldMug:
        """The mug in the gripper, grasped 6 cm above its lower end: with the wrist level (x down) that end
        is at +6 cm along the grasp frame's x, with the wrist turned (x up) at -6 cm."""
        h = self.spec.height_mm / 1000.0
        z = thesis.GRASP_HEIGHT_M
        radius = self.spec.diameter_mm / 2000.0
        if kind is GraspKind.SIDE:
            return HeldMug(f"mug {self.mug.mug_id}", radius, self._delta, z - h, z, self._reach)
        return HeldMug(f"mug {self.mug.mug_id}", radius, self._delta, -z, h - z, self._reach)


class _Builder:
    """Accumulates the motions of a cycle, each starting where the previous one ended."""

    def __init__(self, planner: CyclePlanner, start: FloatArray) -> None:
        self.p = planner
        self.q = start
        self.motions: list[_Motion] = []

    def fork(self) -> _Builder:
        """A builder continuing from here whose motions can be adopted or dropped."""
        trial = _Builder(self.p, self.q.copy())
        trial.motions = list(self.motions)
        return trial

    def adopt(self, trial: _Builder) -> None:
        self.q = trial.q
        self.motions = trial.motions

    def rise(
        self, phase: str, z: float, world: CollisionWorld, *, aperture: float, ignore: Ignore = ""
    ) -> None:
        """Straight up to height ``z`` keeping the present orientation as well as the arm allows."""
        p, _ = self.p.arm.fk(self.q)
        if p[2] < z:
            self.line(
                phase, GraspTarget((float(p[0]), float(p[1]), z)), world, aperture=aperture, ignore=ignore
            )

    def gripper(self, phase: str, kind: StepKind, aperture_m: float | None = None) -> None:
        still = self.p._plan(self.q[None, :], phase)[1]
        self.motions.append(_Motion(Step(phase, kind, aperture_m=aperture_m), still, 0.0))

    def joint_move(
        self,
        phase: str,
        goal: GraspTarget,
        world: CollisionWorld,
        *,
        aperture: float,
        held: HeldMug | None = None,
        mass: float = 0.0,
    ) -> None:
        q_goal = self._solve(goal, self.q, phase)
        self._add(
            phase,
            np.array([self.q, q_goal]),
            world,
            aperture=aperture,
            held=held,
            mass=mass,
            fine=False,
            length=0.0,
        )

    def line(
        self,
        phase: str,
        goal: GraspTarget,
        world: CollisionWorld,
        *,
        aperture: float,
        held: HeldMug | None = None,
        mass: float = 0.0,
        ignore: Ignore = "",
    ) -> None:
        """A straight Cartesian move of the grasp point at fine speed, orientation per ``goal.kind``."""
        start_p, _ = self.p.arm.fk(self.q)
        end_p = np.asarray(goal.position_m)
        length = float(np.linalg.norm(end_p - start_p))
        n = max(2, math.ceil(length / 0.01) + 1)
        targets = [
            GraspTarget(_point(start_p + (end_p - start_p) * f), goal.kind) for f in np.linspace(0, 1, n)[1:]
        ]
        self._follow(
            phase,
            targets,
            world,
            aperture=aperture,
            held=held,
            mass=mass,
            fine=True,
            length=length,
            ignore=ignore,
        )

    def arc(
        self,
        phase: str,
        goal: GraspTarget,
        world: CollisionWorld,
        *,
        aperture: float,
        held: HeldMug | None = None,
        mass: float = 0.0,
    ) -> None:
        """Carry along the arc between the bearings, radius and height blended. The arc turns the way the
        shoulder can: the shorter way unless that passes the shoulder-turn limit."""
        start_p, _ = self.p.arm.fk(self.q)
        a0 = math.atan2(start_p[1], start_p[0])
        a1 = math.atan2(goal.position_m[1], goal.position_m[0])
        span = math.remainder(a1 - a0, 2 * math.pi)
        turn = float(self.q[0])
        lo, hi = float(self.p.arm.lower[0]), float(self.p.arm.upper[0])
        if not lo <= turn + span <= hi:
            span -= math.copysign(2 * math.pi, span)
        r0, r1 = math.hypot(start_p[0], start_p[1]), math.hypot(goal.position_m[0], goal.position_m[1])
        z0, z1 = float(start_p[2]), goal.position_m[2]
        n = max(2, math.ceil(max(abs(span) / math.radians(3), abs(r1 - r0) / 0.02, abs(z1 - z0) / 0.02)) + 1)
        targets = []
        for f in np.linspace(0, 1, n)[1:]:
            a, r, z = a0 + span * f, r0 + (r1 - r0) * f, z0 + (z1 - z0) * f
            targets.append(GraspTarget((r * math.cos(a), r * math.sin(a), z), goal.kind))
        self._follow(phase, targets, world, aperture=aperture, held=held, mass=mass, fine=False, length=0.0)

    def _follow(
        self,
        phase: str,
        targets: Sequence[GraspTarget],
        world: CollisionWorld,
        *,
        aperture: float,
        held: HeldMug | None,
        mass: float,
        fine: bool,
        length: float,
        ignore: Ignore = "",
    ) -> None:
        qs = [self.q]
        for t in targets:
            q = self._solve(t, qs[-1], phase)
            jump = float(np.max(np.abs(q - qs[-1])))
            if jump > _MAX_JOINT_STEP_RAD:
                raise MotionRefused(
                    f"{phase}: the arm would jump {jump:.2f} rad between close waypoints near {_fmt_point(t)}"
                )
            qs.append(q)
        self._add(
            phase,
            np.array(qs),
            world,
            aperture=aperture,
            held=held,
            mass=mass,
            fine=fine,
            length=length,
            ignore=ignore,
        )

    def _solve(self, target: GraspTarget, seed: JointValues, phase: str) -> FloatArray:
        """IK for a target, first moved by the calibration correction (if any) so the real arm gets there."""
        command = target
        if self.p.correction is not None:
            command = GraspTarget(self.p.correction.correct(target.position_m), target.kind)
        result = self.p.arm.ik(command, seeds=[seed])
        if not result.ok or result.q is None:
            x, y, z = target.position_m
            raise MotionRefused(f"{phase}: ({x:.3f}, {y:.3f}, {z:.3f}) m unreachable: {result.reason}")
        return np.asarray(result.q)

    def _add(
        self,
        phase: str,
        waypoints: FloatArray,
        world: CollisionWorld,
        *,
        aperture: float,
        held: HeldMug | None,
        mass: float,
        fine: bool,
        length: float,
        ignore: Ignore = "",
    ) -> None:
        trajectory, path = self.p._plan(waypoints, phase, tool_length_m=length, fine=fine)
        if path.duration == 0.0:
            return
        ids = {ignore} if isinstance(ignore, str) else ignore
        skip = frozenset(f"mug {i}" for i in ids if i)
        if held is not None:
            skip = skip | {held.name}
        hit = world.first_collision(trajectory.positions, aperture_m=aperture, held=held, ignore=skip)
        if hit is not None:
            raise MotionRefused(f"{phase}: {hit}", blockers=hit.mug_ids)
        lateral = held.lateral if held is not None else 0.0
        self.motions.append(_Motion(Step(phase, StepKind.MOVE, trajectory), path, mass, lateral))
        self.q = trajectory.positions[-1].copy()


# The two ways of holding the inverted mug, in the order they are tried (``CyclePlanner._either_roll``).
_ROLLS = (GraspKind.SIDE_UPSIDE_DOWN, GraspKind.SIDE)
# Slots and tray states whose shared motions a planner remembers (one job has a few dozen).
_REMEMBERED = 256


class _Undecided(Exception):
    """What every candidate shares could not be worked out apart from them: plan each on its own."""


def _either(first: MotionRefused | None, second: MotionRefused | None) -> MotionRefused:
    """The refusal of a part of the cycle with either wrist roll, worded as ``_either_roll`` words it."""
    assert first is not None
    assert second is not None
    why = str(first) if str(first) == str(second) else f"{first}; with the wrist level: {second}"
    return MotionRefused.combining(why, (first, second))


# Mugs a move may touch: one mug id, or several (a gripper lifting off the mugs it straddles).
Ignore = str | frozenset[str]


# A mug's handle seen from above (thesis mugs: a loop about 1 cm thick), and the room it must keep from a
# placed mug; the tolerance the packing leaves between footprints is 1 cm.
HANDLE_HALF_THICKNESS_M = 0.005
HANDLE_CLEARANCE_M = 0.002

Segment = tuple[tuple[float, float], tuple[float, float]]


def _handle_bar(x: float, y: float, spec: MugSpec, yaw: float) -> Segment:
    """The handle's centre line from the mug's wall out to its width, for a mug standing at (x, y)."""
    r = spec.diameter_mm / 2000.0
    out = spec.width_mm / 1000.0 - r - HANDLE_HALF_THICKNESS_M
    c, s = math.cos(yaw), math.sin(yaw)
    return (x + r * c, y + r * s), (x + out * c, y + out * s)


def _segment_point_m(seg: Segment, p: tuple[float, float]) -> float:
    (ax, ay), (bx, by) = seg
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / length2))
    return math.hypot(p[0] - (ax + t * dx), p[1] - (ay + t * dy))


def _segment_segment_m(a: Segment, b: Segment) -> float:
    """Distance between two segments in the plane: 0 when they cross, else the nearest endpoint's."""

    def side(p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]) -> float:
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    if side(*a, b[0]) * side(*a, b[1]) < 0 and side(*b, a[0]) * side(*b, a[1]) < 0:
        return 0.0
    return min(
        _segment_point_m(a, b[0]),
        _segment_point_m(a, b[1]),
        _segment_point_m(b, a[0]),
        _segment_point_m(b, a[1]),
    )


def _at_z(target: GraspTarget, z: float) -> GraspTarget:
    return GraspTarget((target.position_m[0], target.position_m[1], z), target.kind)


def _xy_at(target: GraspTarget, z: float) -> tuple[float, float, float]:
    return (target.position_m[0], target.position_m[1], z)


def _point(p: FloatArray) -> tuple[float, float, float]:
    return float(p[0]), float(p[1]), float(p[2])


def _fmt_point(target: GraspTarget) -> str:
    x, y, z = target.position_m
    return f"({x:.3f}, {y:.3f}, {z:.3f}) m"
