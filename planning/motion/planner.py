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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import structlog

from drivers.interfaces import FloatArray, JointTrajectory
from planning import thesis
from planning.arm.description import JOINT_LIMITS
from planning.arm.grasp import lateral_offset_m, side_grasp
from planning.arm.model import ArmModel, JointValues
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import CyclePlan, MotionRefused, MugPose, Step, StepKind, TraySlot
from planning.motion.cell import CellLayout, carry_height_m
from planning.motion.collision import Box, CollisionWorld, Cylinder, HeldMug, mug_obstacles, tray_walls
from planning.motion.energy import DynamicsEnergyModel
from planning.motion.trajectory import JointPath, plan_path
from planning.thesis import MugSpec

log = structlog.get_logger(__name__)

# The arm's base column (shoulder-turn servo and its bracket) as an obstacle for the gripper.
_BASE_COLUMN = Cylinder("the arm's base", 0.0, 0.0, 0.05, 0.0, 0.11)
_MAX_JOINT_STEP_RAD = 0.35


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
        approach_distance_m: float = 0.06,
        release_gap_m: float = 0.008,
        fine_speed_m_s: float = 0.08,
        gripper_close_s: float = 1.0,
        gripper_open_s: float = 0.6,
        energy_model: DynamicsEnergyModel | None = None,
    ) -> None:
        if not control_rate_hz > 0:
            raise ValueError(f"control_rate_hz must be > 0, got {control_rate_hz}")
        if not catalogue:
            raise ValueError("catalogue must hold at least one mug type")
        self.arm = arm
        self.cell = cell
        self.catalogue = dict(catalogue)
        self.control_rate_hz = control_rate_hz
        self.approach_distance_m = approach_distance_m
        self.release_gap_m = release_gap_m
        self.fine_speed_m_s = fine_speed_m_s
        self.gripper_close_s = gripper_close_s
        self.gripper_open_s = gripper_open_s
        self.energy_model = energy_model or DynamicsEnergyModel(arm)
        tallest = max(m.height_mm for m in self.catalogue.values()) / 1000.0
        self.carry_z_m = carry_height_m(tallest)
        self.open_aperture_m = arm.gripper.aperture_m(JOINT_LIMITS["gripper"].lower_rad)

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        """A joint-space move within the servo limits, refused when either end is invalid or it collides
        with the tray or the base (used for parking and recovery; nothing held)."""
        start = self._checked_q(start_q, "start_q")
        goal = self._checked_q(goal_q, "goal_q")
        trajectory, _ = self._plan(np.array([start, goal]), label)
        world = self._world([], [])
        why = world.first_collision(trajectory.positions, aperture_m=self.open_aperture_m)
        if why:
            raise MotionRefused(f"{label}: {why}")
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
        motions = self._cycle_motions(start, mug, spec, slot, on_tray, counter)
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

    def _cycle_motions(
        self,
        start: FloatArray,
        mug: MugPose,
        spec: MugSpec,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        counter: Sequence[MugPose],
    ) -> list[_Motion]:
        h = spec.height_mm / 1000.0
        carry = self.carry_z_m
        z_grasp = thesis.GRASP_HEIGHT_M
        mass = spec.mass_kg
        others = [m for m in counter if m.mug_id != mug.mug_id]
        placed = list(on_tray)
        delta = lateral_offset_m(spec, self.arm.gripper)
        first_held = HeldMug(f"mug {mug.mug_id}", spec.diameter_mm / 2000.0, delta, -z_grasp, h - z_grasp)
        upside_down_held = HeldMug(
            f"mug {mug.mug_id}", spec.diameter_mm / 2000.0, delta, z_grasp - h, z_grasp
        )
        holding_aperture = spec.diameter_mm / 1000.0
        plan = _Builder(self, start)

        # side_grasp: from behind the mug at carry height, down, forward, close, up.
        pick_kind = GraspKind.SIDE_UPSIDE_DOWN if mug.upside_down else GraspKind.SIDE
        pick = self._grasp(mug.x_m, mug.y_m, spec, pick_kind, z_grasp, f"grasp of mug {mug.mug_id}")
        back = self._backed_off(pick)
        world = self._world(others, placed, target=mug, target_spec=spec)
        plan.joint_move("side_grasp.approach", _at_z(back, carry), world, aperture=self.open_aperture_m)
        plan.line("side_grasp.approach", back, world, aperture=self.open_aperture_m)
        plan.line("side_grasp.approach", pick, world, aperture=self.open_aperture_m, ignore=mug.mug_id)
        plan.gripper("side_grasp.close", StepKind.CLOSE)
        lift_world = self._world(others, placed)
        held = upside_down_held if mug.upside_down else first_held
        plan.line(
            "side_grasp.lift", _at_z(pick, carry), lift_world, aperture=holding_aperture, held=held, mass=mass
        )

        if not mug.upside_down:
            fx, fy = self.cell.flip_area_center_m
            set_down = self._grasp(
                fx, fy, spec, GraspKind.SIDE_UPSIDE_DOWN, h - z_grasp + self.release_gap_m, "flip set-down"
            )
            above_flip = GraspTarget(_xy_at(set_down, carry), GraspKind.SIDE)
            plan.arc(
                "flip.transit", above_flip, lift_world, aperture=holding_aperture, held=first_held, mass=mass
            )
            turned = GraspTarget(above_flip.position_m, GraspKind.SIDE_UPSIDE_DOWN)
            plan.joint_move(
                "flip.turn", turned, lift_world, aperture=holding_aperture, held=first_held, mass=mass
            )
            plan.line(
                "flip.set_down", set_down, lift_world, aperture=holding_aperture, held=first_held, mass=mass
            )
            plan.gripper("flip.release", StepKind.OPEN)
            flipped = MugPose(mug.mug_id, mug.type, fx, fy, upside_down=True)
            flip_world = self._world(others, placed, target=flipped, target_spec=spec)
            regrasp = self._grasp(fx, fy, spec, GraspKind.SIDE_UPSIDE_DOWN, z_grasp, "flip regrasp")
            off = self._backed_off(set_down)
            plan.line("flip.regrasp", off, flip_world, aperture=self.open_aperture_m, ignore=mug.mug_id)
            plan.line("flip.regrasp", self._backed_off(regrasp), flip_world, aperture=self.open_aperture_m)
            plan.line("flip.regrasp", regrasp, flip_world, aperture=self.open_aperture_m, ignore=mug.mug_id)
            plan.gripper("flip.close", StepKind.CLOSE)
            plan.line(
                "flip.lift",
                _at_z(regrasp, carry),
                lift_world,
                aperture=holding_aperture,
                held=upside_down_held,
                mass=mass,
            )

        place = self._grasp(
            slot.x_m,
            slot.y_m,
            spec,
            GraspKind.SIDE_UPSIDE_DOWN,
            z_grasp + self.release_gap_m,
            f"slot of {mug.mug_id}",
        )
        held = upside_down_held
        plan.arc(
            "place.transit", _at_z(place, carry), lift_world, aperture=holding_aperture, held=held, mass=mass
        )
        plan.line("place.descend", place, lift_world, aperture=holding_aperture, held=held, mass=mass)
        plan.gripper("place.release", StepKind.OPEN)
        placed_now = MugPose(mug.mug_id, mug.type, slot.x_m, slot.y_m, upside_down=True)
        done_world = self._world(others, placed, target=placed_now, target_spec=spec)
        retreat = self._backed_off(place)
        plan.line("place.retreat", retreat, done_world, aperture=self.open_aperture_m, ignore=mug.mug_id)
        plan.line("place.retreat", _at_z(retreat, carry), done_world, aperture=self.open_aperture_m)
        return plan.motions

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

    def _backed_off(self, target: GraspTarget) -> GraspTarget:
        """The same grasp ``approach_distance_m`` back along the approach (towards the base)."""
        approach = target.approach()
        assert approach is not None
        x, y, z = target.position_m
        d = self.approach_distance_m
        return GraspTarget((x - d * approach[0], y - d * approach[1], z), target.kind)

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
        x0, y0, x1, y1 = self.cell.tray_bounds_m
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
    ) -> CollisionWorld:
        cylinders: list[Cylinder] = [_BASE_COLUMN]
        for m in counter:
            cylinders += mug_obstacles(
                f"mug {m.mug_id}",
                m.x_m,
                m.y_m,
                self._spec(m.type, f"mug {m.mug_id}"),
                handle_yaw_rad=m.handle_yaw_rad,
            )
        for s in placed:
            yaw = math.pi / 2 if s.rotated else 0.0
            cylinders += mug_obstacles(
                f"mug {s.mug_id}", s.x_m, s.y_m, self._spec(s.type, f"mug {s.mug_id}"), handle_yaw_rad=yaw
            )
        if target is not None and target_spec is not None:
            cylinders += mug_obstacles(
                f"mug {target.mug_id}",
                target.x_m,
                target.y_m,
                target_spec,
                handle_yaw_rad=target.handle_yaw_rad,
            )
        walls: list[Box] = tray_walls(
            self.cell.tray_bounds_m,
            height=self.cell.tray_wall_height_m,
            thickness=self.cell.tray_wall_thickness_m,
        )
        return CollisionWorld(self.arm, cylinders, walls)


class _Builder:
    """Accumulates the motions of a cycle, each starting where the previous one ended."""

    def __init__(self, planner: CyclePlanner, start: FloatArray) -> None:
        self.p = planner
        self.q = start
        self.motions: list[_Motion] = []

    def gripper(self, phase: str, kind: StepKind) -> None:
        still = self.p._plan(self.q[None, :], phase)[1]
        self.motions.append(_Motion(Step(phase, kind), still, 0.0))

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
        ignore: str = "",
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
        """Carry along the arc between the bearings (the shorter way), radius and height blended."""
        start_p, _ = self.p.arm.fk(self.q)
        a0 = math.atan2(start_p[1], start_p[0])
        a1 = math.atan2(goal.position_m[1], goal.position_m[0])
        span = math.remainder(a1 - a0, 2 * math.pi)
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
        ignore: str = "",
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
        result = self.p.arm.ik(target, seeds=[seed])
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
        ignore: str = "",
    ) -> None:
        trajectory, path = self.p._plan(waypoints, phase, tool_length_m=length, fine=fine)
        skip = frozenset({f"mug {ignore}"}) if ignore else frozenset()
        if held is not None:
            skip = skip | {held.name}
        why = world.first_collision(trajectory.positions, aperture_m=aperture, held=held, ignore=skip)
        if why:
            raise MotionRefused(f"{phase}: {why}")
        lateral = held.lateral if held is not None else 0.0
        self.motions.append(_Motion(Step(phase, StepKind.MOVE, trajectory), path, mass, lateral))
        self.q = trajectory.positions[-1].copy()


def _at_z(target: GraspTarget, z: float) -> GraspTarget:
    return GraspTarget((target.position_m[0], target.position_m[1], z), target.kind)


def _xy_at(target: GraspTarget, z: float) -> tuple[float, float, float]:
    return (target.position_m[0], target.position_m[1], z)


def _point(p: FloatArray) -> tuple[float, float, float]:
    return float(p[0]), float(p[1]), float(p[2])


def _fmt_point(target: GraspTarget) -> str:
    x, y, z = target.position_m
    return f"({x:.3f}, {y:.3f}, {z:.3f}) m"
