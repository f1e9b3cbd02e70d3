"""What every stage of a cycle shares: the ``Stage`` protocol, the ``CycleContext`` of one mug's cycle,
and the close-and-lift both grasps end with."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from description import thesis
from description.thesis import MugSpec
from planning.arm.grasp import lateral_offset_m, reach_past_axis_m
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import MugPose, StepKind, TraySlot
from planning.motion.builder import Builder, at_z
from planning.motion.collision import HeldMug
from planning.motion.scene import Scene


class Stage(Protocol):
    """One part of a pick-flip-place cycle, as MoveIt Task Constructor has stages: it plans its moves onto
    a ``Builder`` from where the builder is, or raises ``MotionRefused`` and leaves the builder as it was
    only when it is a trial (``Builder.fork``); containers (``Fallbacks``) try their children that way."""

    @property
    def name(self) -> str:
        """The stage's name, for listings and refusals."""
        ...

    @property
    def phases(self) -> tuple[str, ...]:
        """The chart's leaves (``Step.phase``) whose steps this stage may plan, in order."""
        ...

    def plan(self, b: Builder, c: CycleContext) -> None:
        """Add this stage's moves to ``b`` for the cycle ``c``; ``MotionRefused`` saying why it cannot."""
        ...


class CycleContext:
    """What every stage of one mug's cycle needs: the mug, its slot, the obstacles and how it is held."""

    def __init__(
        self,
        scene: Scene,
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
        self.lift_world = scene.world(self.others, self.placed)
        self.set_down: GraspTarget | None = None  # where ``Flip`` left the mug upside down
        self._delta = lateral_offset_m(spec, scene.arm.gripper)
        self._reach = reach_past_axis_m(spec, scene.arm.gripper)

    def held(self, kind: GraspKind) -> HeldMug:
        """The mug in the gripper, grasped 6 cm above its lower end: with the wrist level (x down) that end
        is at +6 cm along the grasp frame's x, with the wrist turned (x up) at -6 cm."""
        h = self.spec.height_mm / 1000.0
        z = thesis.GRASP_HEIGHT_M
        radius = self.spec.diameter_mm / 2000.0
        if kind is GraspKind.SIDE:
            return HeldMug(f"mug {self.mug.mug_id}", radius, self._delta, z - h, z, self._reach)
        return HeldMug(f"mug {self.mug.mug_id}", radius, self._delta, -z, h - z, self._reach)


def lower_onto(b: Builder, c: CycleContext, phase: str, target: GraspTarget, held: HeldMug) -> None:
    """``phase``: lower the held mug onto ``target`` at fine speed to ``set_down_slow_m`` above it, then
    the rest at ``set_down_speed_m_s``. The mug swings about the pads while it is carried and settles
    slowly; let go while it still leans and its brim lands off the target by its height times the lean
    (5 mm for a small mug at 3.5 degrees, measured in the MuJoCo cell), which uses up the clearance the
    placement plan keeps. The slow last stretch gives it the time to hang straight."""
    settings = b.scene.settings
    if settings.set_down_slow_m == 0.0:  # all at fine speed (as recordings made before the setting planned)
        b.line(phase, target, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        return
    above = at_z(target, target.position_m[2] + settings.set_down_slow_m)
    b.line(phase, above, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
    slow = settings.set_down_speed_m_s
    b.line(phase, target, c.lift_world, speed_m_s=slow, aperture=c.holding, held=held, mass=c.mass)


def close_and_lift(b: Builder, c: CycleContext, kind: GraspKind, state: str, grasp: GraspTarget) -> None:
    """``<state>.close`` on the mug at ``grasp``, then ``<state>.lift`` it straight up to carry height."""
    b.gripper(f"{state}.close", StepKind.CLOSE)
    b.line(
        f"{state}.lift",
        at_z(grasp, b.scene.carry_z_m),
        c.lift_world,
        aperture=c.holding,
        held=c.held(kind),
        mass=c.mass,
    )
