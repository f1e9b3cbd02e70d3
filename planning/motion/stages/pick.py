"""Pick: the side grasp of a mug standing on the counter (the chart's ``side_grasp``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from description import thesis
from planning.arm.targets import GraspKind, GraspTarget
from planning.interfaces import MotionRefused, StepKind
from planning.motion.builder import Builder, at_z
from planning.motion.collision import CollisionWorld
from planning.motion.stages.base import CycleContext, close_and_lift


@dataclass(frozen=True, slots=True)
class Pick:
    """side_grasp: from above and behind the mug down to grasp height, in, close, up; holding the mug with
    the wrist ``kind``."""

    kind: GraspKind = GraspKind.SIDE
    name: ClassVar[str] = "pick"
    phases: ClassVar[tuple[str, ...]] = ("side_grasp.approach", "side_grasp.close", "side_grasp.lift")

    def plan(self, b: Builder, c: CycleContext) -> None:
        scene = b.scene
        pick = scene.grasp(
            c.mug.x_m, c.mug.y_m, c.spec, self.kind, thesis.GRASP_HEIGHT_M, f"grasp of mug {c.mug.mug_id}"
        )
        world = scene.world(c.others, c.placed, target=c.mug, target_spec=c.spec)
        _approach(b, pick, world, c.mug.mug_id)
        close_and_lift(b, c, self.kind, "side_grasp", pick)


def _approach(plan: Builder, pick: GraspTarget, world: CollisionWorld, mug_id: str) -> None:
    """side_grasp.approach: to above the pre-grasp point at carry height, down, then in to the grasp.
    The pre-grasp point is behind the mug along the approach when that is reachable and clear, else
    closer, else right above the grasp (the open gripper straddles the mug on the way down)."""
    scene = plan.scene
    opened = scene.open_aperture_m
    carry = scene.carry_z_m
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

    def approach(b: Builder, d: float, side: float) -> None:
        pre = scene.clear_of(pick, d, side)
        above = at_z(pre, max(carry, pre.position_m[2]))
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
        b.line(phase, scene.clear_of(pick, 0.0, side), world, aperture=opened, ignore=mug_id)
        b.line(phase, pick, world, aperture=opened, ignore=mug_id)

    plan.try_offsets(phase, approach)
