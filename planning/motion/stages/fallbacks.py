"""Fallbacks: alternatives tried in order, the first that plans kept (MoveIt Task Constructor's container of
that name); the cycle's wrist-roll fallbacks are two of them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from planning.arm.targets import GraspKind
from planning.interfaces import MotionRefused
from planning.motion.builder import Builder
from planning.motion.stages.base import CycleContext, Stage
from planning.motion.stages.pick import Pick
from planning.motion.stages.place import Place
from planning.motion.stages.regrasp import Regrasp

# The two ways of holding the inverted mug, in the order they are tried, with how a refusal names them: the
# wrist turned (finger on the mug's right, as the thesis did), then level (finger on the left).
ROLLS: tuple[tuple[GraspKind, str], ...] = (
    (GraspKind.SIDE_UPSIDE_DOWN, "wrist turned"),
    (GraspKind.SIDE, "wrist level"),
)

# The stages of an alternative, holding the mug with a wrist roll.
_StagesFor = Callable[[GraspKind], Sequence[Stage]]


@dataclass(frozen=True, slots=True)
class Alternative:
    """One way of doing a part of the cycle: its label (in refusals) and its stages, planned in turn."""

    label: str
    stages: tuple[Stage, ...]


@dataclass(frozen=True, slots=True)
class Fallbacks:
    """Plans each alternative on a trial of the builder in turn and keeps the first that works; when none
    does, refuses with the first one's reason and the last one's (named by its label) when they differ."""

    name: str
    alternatives: tuple[Alternative, ...]

    @property
    def phases(self) -> tuple[str, ...]:
        seen: dict[str, None] = {}
        for alternative in self.alternatives:
            for stage in alternative.stages:
                seen.update(dict.fromkeys(stage.phases))
        return tuple(seen)

    def plan(self, b: Builder, c: CycleContext) -> None:
        reasons: list[tuple[str, MotionRefused]] = []
        for alternative in self.alternatives:
            trial = b.fork()
            try:
                for stage in alternative.stages:
                    stage.plan(trial, c)
            except MotionRefused as e:
                reasons.append((alternative.label, e))
                continue
            b.adopt(trial)
            return
        (_, first), (label, last) = reasons[0], reasons[-1]
        why = str(first) if str(first) == str(last) else f"{first}; with the {label}: {last}"
        raise MotionRefused.combining(why, (e for _, e in reasons))


def pick_and_place_either_roll() -> Fallbacks:
    """A mug already upside down: no flip; either wrist roll can pick it and place it."""
    return _either_roll("pick and place", lambda kind: (Pick(kind), Place(kind)))


def regrasp_and_place_either_roll() -> Fallbacks:
    """Finish the cycle of a flipped mug holding it with either wrist roll: between close neighbours on the
    tray the opening finger needs the free side."""
    return _either_roll("regrasp and place", lambda kind: (Regrasp(kind), Place(kind)))


def _either_roll(what: str, stages: _StagesFor) -> Fallbacks:
    return Fallbacks(
        f"{what}, either wrist roll",
        tuple(Alternative(label, tuple(stages(kind))) for kind, label in ROLLS),
    )
