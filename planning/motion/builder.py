"""Building a cycle's path: joint moves, straight lines, carrying arcs and gripper steps, each starting where
the previous one ended, each timed within the servo limits and checked for collisions as it is added.

A ``Builder`` can be forked to try a way of doing something and the trial adopted or dropped, which is how
the stages try their alternatives (back-off distances, release openings, wrist rolls).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Required, TypedDict, Unpack

import numpy as np

from drivers.interfaces import FloatArray
from planning.arm.model import JointValues
from planning.arm.targets import GraspTarget
from planning.interfaces import MotionRefused, Step, StepKind
from planning.motion.collision import CollisionWorld, HeldMug
from planning.motion.scene import Scene
from planning.motion.trajectory import JointPath

_MAX_JOINT_STEP_RAD = 0.35
# ``np.max`` of a vector without its Python wrapper (the same reduction, asked once per IK waypoint).
_largest = np.maximum.reduce
_POSE_SUFFIX = re.compile(r" \(pose \d+ of \d+\)$")

# Mugs a move may touch: one mug id, or several (a gripper lifting off the mugs it straddles).
Ignore = str | frozenset[str]


@dataclass(frozen=True, slots=True)
class Motion:
    """One planned move with what the collision check and the energy model need."""

    step: Step
    path: JointPath
    payload_kg: float
    payload_lateral_m: float = 0.0


class Carrying(TypedDict, total=False):
    """What a move (``joint_move``, ``line``, ``arc``) carries through the world: the gripper's opening
    ``aperture`` (required), the mug it holds (``held``) and that mug's ``mass``, and the mugs it may touch
    (``ignore``)."""

    aperture: Required[float]
    held: HeldMug | None
    mass: float
    ignore: Ignore


@dataclass(frozen=True, slots=True)
class _Checks:
    """How one segment is timed and checked: what it carries (``Carrying``) through the ``world`` it must not
    hit, and whether it runs at fine speed along a tool path of ``length`` metres (a straight line) or at
    joint speed."""

    world: CollisionWorld
    aperture: float
    held: HeldMug | None = None
    mass: float = 0.0
    ignore: Ignore = ""
    fine: bool = False
    length: float = 0.0
    speed: float | None = None  # the tool's top speed along a line (None: fine speed)


class Builder:
    """Accumulates the motions of a cycle, each starting where the previous one ended."""

    def __init__(self, scene: Scene, start: FloatArray) -> None:
        self.scene = scene
        self.q = start
        self.motions: list[Motion] = []

    def fork(self) -> Builder:
        """A builder continuing from here whose motions can be adopted or dropped."""
        trial = Builder(self.scene, self.q.copy())
        trial.motions = list(self.motions)
        return trial

    def adopt(self, trial: Builder) -> None:
        """Continue from where ``trial`` ended, with its motions."""
        self.q = trial.q
        self.motions = trial.motions

    def rise(
        self, phase: str, z: float, world: CollisionWorld, *, aperture: float, ignore: Ignore = ""
    ) -> None:
        """Straight up to height ``z`` keeping the present orientation as well as the arm allows."""
        p, _ = self.scene.arm.fk(self.q)
        if p[2] < z:
            self.line(
                phase, GraspTarget((float(p[0]), float(p[1]), z)), world, aperture=aperture, ignore=ignore
            )

    def gripper(self, phase: str, kind: StepKind, aperture_m: float | None = None) -> None:
        """Open or close the gripper where the arm is (``aperture_m``: how far an OPEN opens)."""
        still = self.scene.path(self.q[None, :], phase)[1]
        self.motions.append(Motion(Step(phase, kind, aperture_m=aperture_m), still, 0.0))

    def joint_move(
        self, phase: str, goal: GraspTarget, world: CollisionWorld, **carrying: Unpack[Carrying]
    ) -> None:
        """A move in joint space to the IK solution of ``goal`` nearest the present joint angles."""
        q_goal = self._solve(goal, self.q, phase)
        self._add(phase, np.array([self.q, q_goal]), _Checks(world, **carrying))

    def line(
        self,
        phase: str,
        goal: GraspTarget,
        world: CollisionWorld,
        *,
        speed_m_s: float | None = None,
        **carrying: Unpack[Carrying],
    ) -> None:
        """A straight Cartesian move of the grasp point at fine speed (or ``speed_m_s``), orientation per
        ``goal.kind``."""
        start_p, _ = self.scene.arm.fk(self.q)
        end_p = np.asarray(goal.position_m)
        length = float(np.linalg.norm(end_p - start_p))
        n = max(2, math.ceil(length / 0.01) + 1)
        # Every waypoint as ``start_p + (end_p - start_p) * f`` worked out one by one: the same numbers.
        points = start_p + (end_p - start_p) * np.linspace(0, 1, n)[1:, None]
        targets = [GraspTarget((x, y, z), goal.kind) for x, y, z in points.tolist()]
        self._follow(phase, targets, _Checks(world, **carrying, fine=True, length=length, speed=speed_m_s))

    def arc(self, phase: str, goal: GraspTarget, world: CollisionWorld, **carrying: Unpack[Carrying]) -> None:
        """Carry along the arc between the bearings, radius and height blended. The arc turns the way the
        shoulder can: the shorter way unless that passes the shoulder-turn limit."""
        arm = self.scene.arm
        start_p, _ = arm.fk(self.q)
        a0 = math.atan2(start_p[1], start_p[0])
        a1 = math.atan2(goal.position_m[1], goal.position_m[0])
        span = math.remainder(a1 - a0, 2 * math.pi)
        turn = float(self.q[0])
        lo, hi = float(arm.lower[0]), float(arm.upper[0])
        if not lo <= turn + span <= hi:
            span -= math.copysign(2 * math.pi, span)
        r0, r1 = math.hypot(start_p[0], start_p[1]), math.hypot(goal.position_m[0], goal.position_m[1])
        z0, z1 = float(start_p[2]), goal.position_m[2]
        n = max(2, math.ceil(max(abs(span) / math.radians(3), abs(r1 - r0) / 0.02, abs(z1 - z0) / 0.02)) + 1)
        targets = []
        for f in np.linspace(0, 1, n)[1:]:
            a, r, z = a0 + span * f, r0 + (r1 - r0) * f, z0 + (z1 - z0) * f
            targets.append(GraspTarget((r * math.cos(a), r * math.sin(a), z), goal.kind))
        self._follow(phase, targets, _Checks(world, **carrying))

    def back_off(
        self,
        phase: str,
        grasp: GraspTarget,
        back_m: float,
        side_m: float,
        world: CollisionWorld,
        aperture_m: float,
        mug_id: str,
    ) -> GraspTarget:
        """From an opened grasp on a standing mug to ``Scene.clear_of(grasp, back_m, side_m)``: the thumb
        first steps sideways off the brim, then the gripper backs away along the approach. Backing off on
        the diagonal dragged the mug along by the thumb's friction (12-17 mm in the MuJoCo cell), into the
        next mug on the tray. Returns where it ends."""
        clear_of = self.scene.clear_of
        if side_m > 0.0:
            self.line(phase, clear_of(grasp, 0.0, side_m), world, aperture=aperture_m, ignore=mug_id)
        clear = clear_of(grasp, back_m, side_m)
        self.line(phase, clear, world, aperture=aperture_m, ignore=mug_id)
        return clear

    def try_offsets(
        self,
        phase: str,
        moves: Callable[[Builder, float, float], object],
        *,
        sides: Sequence[float] | None = None,
    ) -> None:
        """Plan ``moves`` with the open gripper backed off by each of the settings' ``back_off_m`` in turn,
        first with the thumb ``side_clearance_m`` (or each of ``sides``) off the brim, then touching it
        (tight between neighbours); keep the first that works, or refuse with every reason."""
        settings = self.scene.settings
        reasons: list[MotionRefused] = []
        for back in settings.back_off_m:
            for side in (settings.side_clearance_m, 0.0) if sides is None else sides:
                trial = self.fork()
                try:
                    moves(trial, back, side)
                except MotionRefused as e:
                    reasons.append(e)
                    continue
                self.adopt(trial)
                return
        first, last = (str(reasons[i]).removeprefix(f"{phase}: ") for i in (0, -1))
        if _POSE_SUFFIX.sub("", first) == _POSE_SUFFIX.sub("", last):
            raise MotionRefused.combining(f"{phase}: {first}", reasons)
        raise MotionRefused.combining(f"{phase}: {first}; straight from above: {last}", reasons)

    def _follow(self, phase: str, targets: Sequence[GraspTarget], checks: _Checks) -> None:
        """Through ``targets`` by IK from each to the next (refused where the arm would jump)."""
        qs = [self.q]
        for t in targets:
            q = self._solve(t, qs[-1], phase)
            jump = float(_largest(abs(q - qs[-1])))
            if jump > _MAX_JOINT_STEP_RAD:
                raise MotionRefused(
                    f"{phase}: the arm would jump {jump:.2f} rad between close waypoints near {fmt_point(t)}"
                )
            qs.append(q)
        self._add(phase, np.array(qs), checks)

    def _solve(self, target: GraspTarget, seed: JointValues, phase: str) -> FloatArray:
        """IK for a target, first moved by the calibration correction (if any) so the real arm gets there."""
        command = target
        correction = self.scene.settings.correction
        if correction is not None:
            command = GraspTarget(correction.correct(target.position_m), target.kind)
        result = self.scene.ik(command, seed)
        if not result.ok or result.q is None:
            x, y, z = target.position_m
            raise MotionRefused(f"{phase}: ({x:.3f}, {y:.3f}, {z:.3f}) m unreachable: {result.reason}")
        return np.asarray(result.q)

    def _add(self, phase: str, waypoints: FloatArray, checks: _Checks) -> None:
        """The move through ``waypoints``, timed and checked for collisions, appended (nothing when it
        would take no time)."""
        c = checks
        trajectory, path = self.scene.path(
            waypoints, phase, tool_length_m=c.length, fine=c.fine, tool_speed_m_s=c.speed
        )
        if path.duration == 0.0:
            return
        ids = {c.ignore} if isinstance(c.ignore, str) else c.ignore
        skip = frozenset(f"mug {i}" for i in ids if i)
        if c.held is not None:
            skip = skip | {c.held.name}
        hit = c.world.first_collision(trajectory.positions, aperture_m=c.aperture, held=c.held, ignore=skip)
        if hit is not None:
            raise MotionRefused(f"{phase}: {hit}", blockers=hit.mug_ids)
        lateral = c.held.lateral if c.held is not None else 0.0
        self.motions.append(Motion(Step(phase, StepKind.MOVE, trajectory), path, c.mass, lateral))
        self.q = trajectory.positions[-1].copy()


def at_z(target: GraspTarget, z: float) -> GraspTarget:
    """``target`` moved to height ``z``."""
    return GraspTarget((target.position_m[0], target.position_m[1], z), target.kind)


def xy_at(target: GraspTarget, z: float) -> tuple[float, float, float]:
    """The point above or below ``target`` at height ``z``."""
    return (target.position_m[0], target.position_m[1], z)


def fmt_point(target: GraspTarget) -> str:
    x, y, z = target.position_m
    return f"({x:.3f}, {y:.3f}, {z:.3f}) m"
