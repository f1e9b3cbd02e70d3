"""Regrasp: taking the mug ``Flip`` set down upside down from the side again (the chart's ``flip`` from the
regrasp on)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from description import thesis
from planning.arm.targets import GraspKind
from planning.interfaces import MugPose
from planning.motion.builder import Builder, at_z
from planning.motion.stages.base import CycleContext, close_and_lift


@dataclass(frozen=True, slots=True)
class Regrasp:
    """flip.regrasp .. flip.lift: back off the inverted mug, go to grasp height (turning the wrist if the
    roll ``kind`` is not the one it was set down with), go in, close, lift."""

    kind: GraspKind
    name: ClassVar[str] = "regrasp"
    phases: ClassVar[tuple[str, ...]] = ("flip.regrasp", "flip.close", "flip.lift")

    def plan(self, b: Builder, c: CycleContext) -> None:
        assert c.set_down is not None, "Regrasp plans after Flip"
        kind = self.kind
        scene = b.scene
        set_down = c.set_down
        fx, fy = scene.cell.flip_area_center_m
        opened = scene.open_aperture_m
        regrasp = scene.grasp(fx, fy, c.spec, kind, thesis.GRASP_HEIGHT_M, "flip regrasp")
        flipped = MugPose(c.mug.mug_id, c.mug.type, fx, fy, upside_down=True)
        world = scene.world(c.others, c.placed, target=flipped, target_spec=c.spec)

        def moves(t: Builder, back: float, side: float) -> None:
            off = t.back_off("flip.regrasp", set_down, back, side, world, opened, c.mug.mug_id)
            pre = scene.clear_of(regrasp, back, side)
            if kind is not set_down.kind:
                # Rolling the wrist sweeps the palm round the approach axis: do it up at carry height.
                carry = scene.carry_z_m
                t.line("flip.regrasp", at_z(off, carry), world, aperture=opened)
                t.joint_move("flip.regrasp", at_z(pre, carry), world, aperture=opened)
            t.line("flip.regrasp", pre, world, aperture=opened)
            beside = scene.clear_of(regrasp, 0.0, side)
            t.line("flip.regrasp", beside, world, aperture=opened, ignore=c.mug.mug_id)
            t.line("flip.regrasp", regrasp, world, aperture=opened, ignore=c.mug.mug_id)

        b.try_offsets("flip.regrasp", moves)
        close_and_lift(b, c, kind, "flip", regrasp)
