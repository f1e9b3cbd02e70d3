"""Place: putting the held mug down upside down in its tray slot (the chart's ``place``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from description import thesis
from planning.arm.targets import GraspKind
from planning.interfaces import MotionRefused, MugPose, StepKind
from planning.motion.builder import Builder, at_z
from planning.motion.stages.base import CycleContext, lower_onto


@dataclass(frozen=True, slots=True)
class Place:
    """place: carry to above the slot, descend until the brim is just above the tray, let go, back off;
    the mug held with the wrist ``kind``."""

    kind: GraspKind
    name: ClassVar[str] = "place"
    phases: ClassVar[tuple[str, ...]] = ("place.transit", "place.descend", "place.release", "place.retreat")

    def plan(self, b: Builder, c: CycleContext) -> None:
        scene = b.scene
        settings = scene.settings
        tray_z = scene.cell.tray.base_m
        place_z = tray_z + thesis.GRASP_HEIGHT_M + settings.release_gap_m
        place = scene.grasp(c.slot.x_m, c.slot.y_m, c.spec, self.kind, place_z, f"slot of {c.mug.mug_id}")
        held = c.held(self.kind)
        carry = scene.carry_z_m
        b.arc("place.transit", at_z(place, carry), c.lift_world, aperture=c.holding, held=held, mass=c.mass)
        lower_onto(b, c, "place.descend", place, held)
        placed_now = MugPose(c.mug.mug_id, c.mug.type, c.slot.x_m, c.slot.y_m, upside_down=True)
        done_world = scene.world(
            c.others, c.placed, target=placed_now, target_spec=c.spec, target_floor=tray_z
        )
        reasons: list[MotionRefused] = []
        # Let go opening the jaw just wider than the mug (a full opening swings the finger into a neighbour
        # 1 cm away, the packing tolerance), the thumb stepping off the brim by half that; back off, and
        # open fully once up at carry height. The side step matters more than the width (backing straight
        # off dragged a mug 17 mm), so every opening with it is tried before any without; a full opening at
        # once is the last resort.
        partial = [(c.holding + extra, extra / 2) for extra in settings.release_openings_m]
        releases: list[tuple[float | None, tuple[float, ...]]] = [(a, (side,)) for a, side in partial]
        releases += [(a, (0.0,)) for a, _ in partial]
        releases.append((None, (settings.side_clearance_m, 0.0)))
        for aperture, sides in releases:
            trial = b.fork()
            trial.gripper("place.release", StepKind.OPEN, aperture)
            jaw = scene.open_aperture_m if aperture is None else aperture

            def retreat(t: Builder, back: float, side: float, jaw: float = jaw) -> None:
                clear = t.back_off("place.retreat", place, back, side, done_world, jaw, c.mug.mug_id)
                t.line("place.retreat", at_z(clear, carry), done_world, aperture=jaw)

            try:
                trial.try_offsets("place.retreat", retreat, sides=sides)
                if aperture is not None:
                    hit = done_world.first_collision(trial.q[None, :], aperture_m=scene.open_aperture_m)
                    if hit is not None:
                        raise MotionRefused(
                            f"place.retreat: opening fully at carry height: {hit}", blockers=hit.mug_ids
                        )
                    trial.gripper("place.retreat", StepKind.OPEN)
            except MotionRefused as e:
                reasons.append(e)
                continue
            b.adopt(trial)
            return
        first, last = str(reasons[0]), str(reasons[-1])
        raise MotionRefused.combining(first if first == last else f"{first}; opening fully: {last}", reasons)
