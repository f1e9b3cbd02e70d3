"""Flip: turning the picked mug over in the flip area (the chart's ``flip`` up to the release)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from description import thesis
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import StepKind
from planning.motion.builder import Builder, xy_at
from planning.motion.stages.base import CycleContext, lower_onto


@dataclass(frozen=True, slots=True)
class Flip:
    """flip: carry to above the flip area, turn the wrist by pi, set the mug down upside down, let go.
    Leaves where it set the mug down in ``CycleContext.set_down`` (``Regrasp`` picks it up there)."""

    name: ClassVar[str] = "flip"
    phases: ClassVar[tuple[str, ...]] = ("flip.transit", "flip.turn", "flip.set_down", "flip.release")

    def plan(self, b: Builder, c: CycleContext) -> None:
        scene = b.scene
        fx, fy = scene.cell.flip_area_center_m
        h = c.spec.height_mm / 1000.0
        set_down_z = h - thesis.GRASP_HEIGHT_M + scene.settings.release_gap_m
        set_down = scene.grasp(fx, fy, c.spec, GraspKind.SIDE_UPSIDE_DOWN, set_down_z, "flip set-down")
        above = GraspTarget(xy_at(set_down, scene.carry_z_m), GraspKind.SIDE)
        held = c.held(GraspKind.SIDE)  # the mug stays where it is in the gripper while the wrist turns
        b.arc("flip.transit", above, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        turned = GraspTarget(above.position_m, GraspKind.SIDE_UPSIDE_DOWN)
        b.joint_move("flip.turn", turned, c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        lower_onto(b, c, "flip.set_down", set_down, held)
        b.gripper("flip.release", StepKind.OPEN)
        c.set_down = set_down
