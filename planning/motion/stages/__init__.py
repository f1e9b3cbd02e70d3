"""The stages of a pick-flip-place cycle, each an object that can be named, listed and planned on its own, as
MoveIt Task Constructor has them: ``Pick`` (the side grasp), ``Flip`` (turning the mug over in the flip area),
``Regrasp`` (taking it from the side again), ``Place`` (into its tray slot), and ``Fallbacks`` (alternatives
tried in turn: the wrist-roll fallbacks). ``CyclePlanner.stages`` composes them into a cycle."""

from planning.motion.stages.base import CycleContext, Stage
from planning.motion.stages.fallbacks import (
    ROLLS,
    Alternative,
    Fallbacks,
    pick_and_place_either_roll,
    regrasp_and_place_either_roll,
)
from planning.motion.stages.flip import Flip
from planning.motion.stages.pick import Pick
from planning.motion.stages.place import Place
from planning.motion.stages.regrasp import Regrasp

__all__ = [
    "ROLLS",
    "Alternative",
    "CycleContext",
    "Fallbacks",
    "Flip",
    "Pick",
    "Place",
    "Regrasp",
    "Stage",
    "pick_and_place_either_roll",
    "regrasp_and_place_either_roll",
]
