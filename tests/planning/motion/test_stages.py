"""The cycle's stages on their own: each is named, declares the chart leaves it plans, and plans from where
the builder is; ``Fallbacks`` keeps the first alternative that plans and words a refusal of all of them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pytest

from daemon.config import load_config
from description.thesis import MUG_TYPES
from planning.arm import ArmModel, GraspKind
from planning.interfaces import MotionRefused, MugPose, StepKind, TraySlot
from planning.motion import CyclePlanner
from planning.motion.builder import Builder
from planning.motion.stages import (
    Alternative,
    CycleContext,
    Fallbacks,
    Flip,
    Pick,
    Place,
    Regrasp,
    Stage,
)
from statechart.chart import CYCLE_PHASES

START_Q = (0.0, -1.2, 1.7, -2.0, -math.pi / 2)
MUG = MugPose("m1", "big", -0.10, 0.45, handle_yaw_rad=math.atan2(0.45, -0.10))
NEIGHBOURS = [MugPose("m2", "small", 0.08, 0.45)]
SLOT = TraySlot("m1", "big", 0.45, 0.05)
PLACED = [TraySlot("m4", "small", 0.45, -0.06)]


@pytest.fixture(scope="module")
def planner() -> CyclePlanner:
    return CyclePlanner(ArmModel.load(), load_config().cell, MUG_TYPES)


def _context(planner: CyclePlanner, mug: MugPose = MUG) -> CycleContext:
    spec = MUG_TYPES[mug.type]
    return CycleContext(planner.scene, mug, spec, SLOT, PLACED, [mug, *NEIGHBOURS])


def _start(planner: CyclePlanner) -> Builder:
    return Builder(planner.scene, np.array(START_Q))


def _phases(b: Builder, since: int = 0) -> list[str]:
    return [m.step.phase for m in b.motions[since:]]


def _height(planner: CyclePlanner, b: Builder) -> float:
    return float(planner.arm.fk(b.q)[0][2])


def test_the_cycle_of_an_upright_mug_is_pick_flip_then_regrasp_and_place_with_either_roll(
    planner: CyclePlanner,
) -> None:
    stages = planner.stages()
    assert [s.name for s in stages] == ["pick", "flip", "regrasp and place, either wrist roll"]
    fallbacks = stages[2]
    assert isinstance(fallbacks, Fallbacks)
    assert [(a.label, [s.name for s in a.stages]) for a in fallbacks.alternatives] == [
        ("wrist turned", ["regrasp", "place"]),
        ("wrist level", ["regrasp", "place"]),
    ]
    assert [s.kind for a in fallbacks.alternatives for s in a.stages if isinstance(s, Regrasp)] == [
        GraspKind.SIDE_UPSIDE_DOWN,
        GraspKind.SIDE,
    ]


def test_the_cycle_of_a_mug_upside_down_already_is_pick_and_place_with_either_roll(
    planner: CyclePlanner,
) -> None:
    (stage,) = planner.stages(upside_down=True)
    assert isinstance(stage, Fallbacks)
    assert stage.name == "pick and place, either wrist roll"
    assert [[s.name for s in a.stages] for a in stage.alternatives] == [["pick", "place"], ["pick", "place"]]


def test_every_stage_plans_only_leaves_of_the_chart_and_together_they_cover_the_cycle(
    planner: CyclePlanner,
) -> None:
    every = [p for s in planner.stages() for p in s.phases]
    assert set(every) <= set(CYCLE_PHASES)
    # The leaves the planner leaves to the job (verifying a grasp) are the only ones no stage plans.
    assert set(CYCLE_PHASES) - set(every) == {"side_grasp.verify", "flip.verify"}


def test_pick_opens_goes_in_closes_and_lifts_the_mug_to_carry_height(planner: CyclePlanner) -> None:
    b = _start(planner)
    Pick().plan(b, _context(planner))
    assert set(_phases(b)) == set(Pick.phases)
    assert (b.motions[0].step.phase, b.motions[0].step.kind) == ("side_grasp.approach", StepKind.OPEN)
    close = [m.step for m in b.motions if m.step.kind is StepKind.CLOSE]
    assert [s.phase for s in close] == ["side_grasp.close"]
    assert b.motions[-1].step.phase == "side_grasp.lift"
    assert b.motions[-1].payload_kg == MUG_TYPES["big"].mass_kg
    assert _height(planner, b) == pytest.approx(planner.carry_z_m, abs=1e-3)


def test_flip_sets_the_mug_down_upside_down_and_lets_go(planner: CyclePlanner) -> None:
    b = _start(planner)
    c = _context(planner)
    Pick().plan(b, c)
    picked = len(b.motions)
    assert c.set_down is None
    Flip().plan(b, c)
    assert _phases(b, picked) == [
        "flip.transit",
        "flip.turn",
        "flip.set_down",
        "flip.set_down",
        "flip.release",
    ]
    assert b.motions[-1].step.kind is StepKind.OPEN
    assert c.set_down is not None
    assert c.set_down.kind is GraspKind.SIDE_UPSIDE_DOWN
    np.testing.assert_allclose(planner.arm.fk(b.q)[0], c.set_down.position_m, atol=1e-3)


@pytest.mark.parametrize("kind", [GraspKind.SIDE_UPSIDE_DOWN, GraspKind.SIDE])
def test_regrasp_takes_the_flipped_mug_with_either_roll_and_lifts_it(
    planner: CyclePlanner, kind: GraspKind
) -> None:
    b = _start(planner)
    c = _context(planner)
    Pick().plan(b, c)
    Flip().plan(b, c)
    flipped = len(b.motions)
    Regrasp(kind).plan(b, c)
    phases = _phases(b, flipped)
    assert set(phases) == set(Regrasp.phases)
    assert phases[-2:] == ["flip.close", "flip.lift"]
    assert _height(planner, b) == pytest.approx(planner.carry_z_m, abs=1e-3)


def test_regrasp_before_any_flip_is_a_composition_error(planner: CyclePlanner) -> None:
    with pytest.raises(AssertionError, match="Regrasp plans after Flip"):
        Regrasp(GraspKind.SIDE).plan(_start(planner), _context(planner))


def test_place_puts_a_mug_held_upside_down_in_its_slot_and_backs_off_to_carry_height(
    planner: CyclePlanner,
) -> None:
    mug = MugPose("m1", "big", -0.10, 0.45, handle_yaw_rad=MUG.handle_yaw_rad, upside_down=True)
    b = _start(planner)
    c = _context(planner, mug)
    Pick(GraspKind.SIDE_UPSIDE_DOWN).plan(b, c)
    picked = len(b.motions)
    Place(GraspKind.SIDE_UPSIDE_DOWN).plan(b, c)
    phases = _phases(b, picked)
    assert phases[:2] == ["place.transit", "place.descend"]
    assert set(phases) == set(Place.phases)
    release = next(m.step for m in b.motions[picked:] if m.step.phase == "place.release")
    # Opened just wider than the mug first (a full opening swings the finger into a neighbour).
    assert release.aperture_m is not None
    assert release.aperture_m > MUG_TYPES["big"].diameter_mm / 1000.0
    assert (b.motions[-1].step.phase, b.motions[-1].step.kind) == ("place.retreat", StepKind.OPEN)
    assert _height(planner, b) == pytest.approx(planner.carry_z_m, abs=1e-3)


def _tool_speeds(planner: CyclePlanner, b: Builder, phase: str) -> list[tuple[float, float]]:
    """(height of the grasp point, its speed) along every sample of ``phase``'s moves."""
    out = []
    for m in b.motions:
        traj = m.step.trajectory
        if m.step.phase != phase or traj is None:
            continue
        points = np.array([planner.arm.fk(q)[0] for q in traj.positions])
        speeds = np.linalg.norm(np.diff(points, axis=0), axis=1) / np.diff(traj.times)
        out += [(float(z), float(v)) for z, v in zip(points[1:, 2], speeds, strict=True)]
    return out


@pytest.mark.parametrize("phase", ["flip.set_down", "place.descend"])
def test_the_held_mug_goes_down_its_last_3_cm_slowly_so_it_hangs_straight_when_let_go(
    planner: CyclePlanner, phase: str
) -> None:
    b = _start(planner)
    c = _context(planner)
    Pick().plan(b, c)
    Flip().plan(b, c)
    Regrasp(GraspKind.SIDE_UPSIDE_DOWN).plan(b, c)
    Place(GraspKind.SIDE_UPSIDE_DOWN).plan(b, c)
    settings = planner.scene.settings
    samples = _tool_speeds(planner, b, phase)
    bottom = min(z for z, _ in samples)
    last = [v for z, v in samples if z < bottom + settings.set_down_slow_m - 1e-3]
    higher = [v for z, v in samples if z > bottom + settings.set_down_slow_m + 1e-3]
    assert (
        len(last) * (1 / planner.control_rate_hz)
        >= 0.9 * settings.set_down_slow_m / settings.set_down_speed_m_s
    )
    assert max(last) <= settings.set_down_speed_m_s * 1.1  # the cap is kept along the path to a few %
    assert max(higher) > 2 * settings.set_down_speed_m_s  # the rest at fine speed


def test_a_stage_that_refuses_leaves_a_trial_builder_and_says_where(planner: CyclePlanner) -> None:
    far = TraySlot("m1", "big", 2.0, 0.05)  # out of the arm's reach
    b = _start(planner)
    c = CycleContext(planner.scene, MUG, MUG_TYPES["big"], far, [], [])
    Pick().plan(b, c)
    trial = b.fork()
    with pytest.raises(MotionRefused, match=r"^place\.transit: .* unreachable"):
        Place(GraspKind.SIDE).plan(trial, c)
    assert _phases(b)[-1] == "side_grasp.lift"


@dataclass(frozen=True)
class _Scripted:
    """A stage for testing containers: adds one gripper step, or refuses with ``refusal``."""

    name: str
    refusal: MotionRefused | None = None
    planned: list[str] = field(default_factory=list)
    phases: ClassVar[tuple[str, ...]] = ("place.release",)

    def plan(self, b: Builder, c: CycleContext) -> None:
        self.planned.append(self.name)
        b.gripper("place.release", StepKind.OPEN)
        if self.refusal is not None:
            raise self.refusal


def test_fallbacks_keep_the_first_alternative_that_plans_and_drop_what_the_others_added(
    planner: CyclePlanner,
) -> None:
    planned: list[str] = []
    first = _Scripted("first", MotionRefused("place.retreat: blocked", blockers=("m2",)), planned)
    second = _Scripted("second", None, planned)
    never = _Scripted("never", None, planned)
    fallbacks = Fallbacks(
        "test", (Alternative("a", (first,)), Alternative("b", (second,)), Alternative("c", (never,)))
    )
    stage: Stage = fallbacks
    b = _start(planner)
    stage.plan(b, _context(planner))
    assert planned == ["first", "second"]
    assert len(b.motions) == 1  # the refused alternative's step is not kept


def test_fallbacks_refuse_with_the_first_and_last_reason_and_every_blocker(planner: CyclePlanner) -> None:
    a = _Scripted("a", MotionRefused("place.retreat: hits m2", blockers=("m2",)))
    b_ = _Scripted("b", MotionRefused("place.retreat: hits m3", blockers=("m3",)))
    fallbacks = Fallbacks("test", (Alternative("wrist turned", (a,)), Alternative("wrist level", (b_,))))
    b = _start(planner)
    with pytest.raises(MotionRefused) as refused:
        fallbacks.plan(b, _context(planner))
    assert str(refused.value) == "place.retreat: hits m2; with the wrist level: place.retreat: hits m3"
    assert refused.value.blockers == frozenset({"m2", "m3"})
    assert b.motions == []
    same = Fallbacks("test", (Alternative("x", (a,)), Alternative("y", (a,))))
    with pytest.raises(MotionRefused, match=r"^place\.retreat: hits m2$"):
        same.plan(b, _context(planner))


def test_fallbacks_declare_the_phases_of_their_alternatives_once() -> None:
    fallbacks = Fallbacks(
        "x", (Alternative("a", (Regrasp(GraspKind.SIDE), Place(GraspKind.SIDE))), Alternative("b", ()))
    )
    assert fallbacks.phases == Regrasp.phases + Place.phases
