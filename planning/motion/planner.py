"""The pick-flip-place cycle of one mug (thesis §4.3, Figure 4.18) as checked joint trajectories.

Per mug: approach the counter mug from behind at grasp height and side-grasp it, lift to carry height,
carry it along an arc at constant height to above the flip area, turn the wrist by pi, set the mug down
upside down, let go, back off and regrasp it from the side 6 cm above the counter, lift, carry it to above
its tray slot, descend until its brim is just above the tray, let go and back off. Every motion is sampled at
the control rate within the servo limits and checked for collisions before the plan is returned; anything
unreachable, out of limits, non-finite or colliding raises ``MotionRefused`` and nothing is commanded.

The cycle is composed of stages (``planning.motion.stages``: ``Pick``, ``Flip``, ``Regrasp``, ``Place`` and
the wrist-roll ``Fallbacks``), each planning in the one ``Scene`` the planner builds; ``CyclePlanner.stages``
lists them. This module composes them, validates what it is asked, costs the plan and checks the handle.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import structlog

from description import thesis
from description.cell import CellLayout
from description.thesis import MugSpec
from drivers.interfaces import FloatArray, JointTrajectory
from planning.arm.calibration import PositionCorrection
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import CyclePlan, MotionRefused, MugPose, Step, StepKind, TraySlot
from planning.motion.builder import Builder, Motion, at_z
from planning.motion.energy import DynamicsEnergyModel
from planning.motion.handle import check_handle, handle_yaw_on_tray
from planning.motion.remembered import RememberedCycles
from planning.motion.scene import SET_DOWN_SLOW_M, SET_DOWN_SPEED_M_S, Scene, Settings
from planning.motion.stages import (
    ROLLS,
    CycleContext,
    Flip,
    Pick,
    Place,
    Regrasp,
    Stage,
    pick_and_place_either_roll,
    regrasp_and_place_either_roll,
)
from planning.motion.trajectory import JointPath

log = structlog.get_logger(__name__)

# Slots and tray states whose shared motions a planner remembers (one job has a few dozen).
_REMEMBERED = 256


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
        set_down_slow_m: float = SET_DOWN_SLOW_M,
        set_down_speed_m_s: float = SET_DOWN_SPEED_M_S,
        gripper_close_s: float = 1.0,
        gripper_open_s: float = 0.6,
        energy_model: DynamicsEnergyModel | None = None,
        correction: PositionCorrection | None = None,
    ) -> None:
        if not control_rate_hz > 0:
            raise ValueError(f"control_rate_hz must be > 0, got {control_rate_hz}")
        if not catalogue:
            raise ValueError("catalogue must hold at least one mug type")
        # The last ``set_down_slow_m`` of every set-down (flip and place) runs at ``set_down_speed_m_s``:
        # the held mug then hangs straight when it is let go (``stages.base.lower_onto``).
        if not (set_down_slow_m >= 0 and set_down_speed_m_s > 0):
            raise ValueError(
                f"set_down_slow_m must be >= 0 and set_down_speed_m_s > 0, got {set_down_slow_m}, "
                f"{set_down_speed_m_s}"
            )
        settings = Settings(
            control_rate_hz=control_rate_hz,
            back_off_m=tuple(back_off_m),
            side_clearance_m=side_clearance_m,
            release_gap_m=release_gap_m,
            release_openings_m=tuple(release_openings_m),
            fine_speed_m_s=fine_speed_m_s,
            set_down_slow_m=set_down_slow_m,
            set_down_speed_m_s=set_down_speed_m_s,
            correction=correction,
        )
        self.scene = Scene(arm, cell, catalogue, settings)
        self.gripper_close_s = gripper_close_s
        self.gripper_open_s = gripper_open_s
        self.energy_model = energy_model or DynamicsEnergyModel(arm)
        # The arm model keeps one Pinocchio Data: calls from several threads take turns.
        self._lock = threading.Lock()
        # What every candidate for a slot shares (``_shared_refusals``), by slot and the mugs on the tray.
        self._shared: dict[
            tuple[TraySlot, tuple[TraySlot, ...]], tuple[MotionRefused | None, MotionRefused | None] | None
        ] = {}
        # Every cycle planned, by exactly what it was asked (the plan check and the job ask many again).
        self.remembered = RememberedCycles()
        self._energies = _PathEnergies()

    # What the planner was built with (``scene.settings`` has the rest).

    @property
    def arm(self) -> ArmModel:
        return self.scene.arm

    @property
    def cell(self) -> CellLayout:
        return self.scene.cell

    @property
    def catalogue(self) -> dict[str, MugSpec]:
        return self.scene.catalogue

    @property
    def control_rate_hz(self) -> float:
        return self.scene.settings.control_rate_hz

    @property
    def correction(self) -> PositionCorrection | None:
        return self.scene.settings.correction

    @property
    def carry_z_m(self) -> float:
        """The height mugs are carried at: above the tallest mug of the catalogue on the tray."""
        return self.scene.carry_z_m

    @property
    def open_aperture_m(self) -> float:
        """The gripper's full opening."""
        return self.scene.open_aperture_m

    def __getstate__(self) -> dict[str, object]:
        """Picklable (the daemon may plan in a worker process): the lock and what it remembers stay behind."""
        state = dict(self.__dict__)
        del state["_lock"]
        state["_shared"] = {}
        state["remembered"] = RememberedCycles()
        del state["_energies"]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()
        self._energies = _PathEnergies()

    def stages(self, *, upside_down: bool = False) -> tuple[Stage, ...]:
        """The stages of the cycle of a mug standing upright (pick, flip, then regrasp and place with either
        wrist roll) or already upside down (pick and place with either wrist roll), in the order planned."""
        if upside_down:
            return (pick_and_place_either_roll(),)
        return (Pick(GraspKind.SIDE), Flip(), regrasp_and_place_either_roll())

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
        start = self.scene.checked_q(start_q, "start_q")
        goal = self.scene.checked_q(goal_q, "goal_q")
        with self._lock:
            trajectory, _ = self.scene.path(np.array([start, goal]), label)
            world = self.scene.world(counter, on_tray)
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
        start = self.scene.checked_q(start_q, "start_q")
        spec = self.scene.spec(mug.type, f"mug {mug.mug_id}")
        slot_spec = self.scene.spec(slot.type, f"slot for {slot.mug_id}")
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
        keys = RememberedCycles.keys(start, mug, slot, on_tray, counter)
        with self._lock:
            remembered = self.remembered.plan(keys)  # raises the refusal remembered
            if remembered is not None:
                log.debug("cycle_remembered", mug_id=mug.mug_id)
                self._log_planned(mug, remembered)
                return remembered
            try:
                plan = self._planned_cycle(start, mug, spec, slot, on_tray, counter)
            except MotionRefused as e:
                self.remembered.keep_refusal(keys, e)
                raise
            self.remembered.keep_plan(keys, plan)
            return plan

    def _planned_cycle(
        self,
        start: FloatArray,
        mug: MugPose,
        spec: MugSpec,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        counter: Sequence[MugPose],
    ) -> CyclePlan:
        """``plan_cycle`` worked out (the lock held)."""
        motions = self._cycle_motions(start, mug, spec, slot, on_tray, counter)
        if not mug.handle_seen:
            # Nothing to predict from: the packing's assumption (handle along +x) stands.
            return self._costed(mug, motions)
        handle_yaw = handle_yaw_on_tray(self.arm, mug, motions)
        check_handle(self.scene, mug, slot, spec, handle_yaw, on_tray)
        return replace(self._costed(mug, motions), handle_yaw_rad=handle_yaw)

    def _costed(self, mug: MugPose, motions: Sequence[Motion]) -> CyclePlan:
        """The plan of a cycle's motions with its predicted duration and electrical energy."""
        steps: list[Step] = []
        duration = 0.0
        energy = 0.0
        for m in motions:
            steps.append(m.step)
            if m.step.kind is StepKind.MOVE:
                duration += m.path.duration
                energy += self._path_energy_j(m)
            else:
                wait = self.gripper_close_s if m.step.kind is StepKind.CLOSE else self.gripper_open_s
                duration += wait
                energy += self.energy_model.hold_energy_j(m.path.waypoints[0], wait)
        energy += self.energy_model.idle_energy_j(duration)
        plan = CyclePlan(mug_id=mug.mug_id, steps=tuple(steps), duration_s=duration, energy_j=energy)
        self._log_planned(mug, plan)
        return plan

    def _path_energy_j(self, m: Motion) -> float:
        """The electrical energy of a move, worked out once per timed path and payload: the paths are shared
        (``Scene.path`` remembers them, never changed) and a plan check costs the same moves again in cycle
        after cycle (about half of them, kinematic datasets 1, 3 and 5)."""
        key = (m.payload_kg, m.payload_lateral_m)
        energies = self._energies.setdefault(m.path, {})
        energy = energies.get(key)
        if energy is None:
            energy = self.energy_model.path_energy(
                m.path, self.control_rate_hz, payload_kg=m.payload_kg, payload_lateral_m=m.payload_lateral_m
            ).total_j
            energies[key] = energy
        return energy

    @staticmethod
    def _log_planned(mug: MugPose, plan: CyclePlan) -> None:
        log.info(
            "cycle_planned", mug_id=mug.mug_id, steps=len(plan.steps), duration_s=round(plan.duration_s, 2)
        )

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
            spec = self.scene.spec(slot.type, f"slot for {slot.mug_id}")
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
        scene = self.scene
        c = CycleContext(scene, MugPose(slot.mug_id, slot.type, slot.x_m, slot.y_m), spec, slot, placed, ())
        place_z = self.cell.tray.base_m + thesis.GRASP_HEIGHT_M + scene.settings.release_gap_m
        fx, fy = self.cell.flip_area_center_m
        set_down_z = spec.height_mm / 1000.0 - thesis.GRASP_HEIGHT_M + scene.settings.release_gap_m
        flipped: list[Builder] = []

        def place(kind: GraspKind) -> MotionRefused | None:
            try:
                target = scene.grasp(slot.x_m, slot.y_m, spec, kind, place_z, f"slot of {slot.mug_id}")
            except MotionRefused as e:
                return e
            try:
                Place(kind).plan(Builder(scene, self._above(target)), c)
            except MotionRefused as e:
                return e
            return None

        def regrasp(kind: GraspKind) -> MotionRefused | None:
            if not flipped:
                set_down = scene.grasp(fx, fy, spec, GraspKind.SIDE_UPSIDE_DOWN, set_down_z, "flip set-down")
                flip = Builder(scene, self._above(GraspTarget(set_down.position_m, GraspKind.SIDE)))
                Flip().plan(flip, c)
                flipped.append(flip)
            try:
                Regrasp(kind).plan(flipped[0].fork(), c)
            except MotionRefused as e:
                return e
            return None

        placing: list[MotionRefused | None] = []
        upright: list[MotionRefused] = []
        try:
            for kind, _ in ROLLS:
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
        above = at_z(target, self.carry_z_m)
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
    ) -> list[Motion]:
        c = CycleContext(self.scene, mug, spec, slot, on_tray, counter)
        plan = Builder(self.scene, start)
        for stage in self.stages(upside_down=mug.upside_down):
            stage.plan(plan, c)
        return plan.motions

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


# The energy of each timed path costed, by payload (kg, lateral m): forgotten with the path.
_PathEnergies = weakref.WeakKeyDictionary[JointPath, dict[tuple[float, float], float]]


class _Undecided(Exception):
    """What every candidate shares could not be worked out apart from them: plan each on its own."""


def _either(first: MotionRefused | None, second: MotionRefused | None) -> MotionRefused:
    """The refusal of a part of the cycle with either wrist roll, worded as ``Fallbacks`` words it."""
    assert first is not None
    assert second is not None
    why = str(first) if str(first) == str(second) else f"{first}; with the wrist level: {second}"
    return MotionRefused.combining(why, (first, second))
