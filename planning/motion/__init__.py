"""Motion planning of the pick-flip-place cycle: cell, trajectories, collision checks, time and energy.

``CyclePlanner`` composes the cycle from the stages of ``planning.motion.stages`` (``Pick``, ``Flip``,
``Regrasp``, ``Place``, the wrist-roll ``Fallbacks``); ``CyclePlanner.stages`` lists them."""

from planning.interfaces import MotionPlanner, MotionRefused
from planning.motion.cell import carry_height_m, check_reachable
from planning.motion.energy import DynamicsEnergyModel, EnergyBreakdown, thesis_energy_j
from planning.motion.move_cost import DynamicsMoveCost
from planning.motion.planner import CyclePlanner
from planning.motion.trajectory import JointPath, plan_path

__all__ = [
    "CyclePlanner",
    "DynamicsEnergyModel",
    "DynamicsMoveCost",
    "EnergyBreakdown",
    "JointPath",
    "MotionPlanner",
    "MotionRefused",
    "carry_height_m",
    "check_reachable",
    "plan_path",
    "thesis_energy_j",
]
