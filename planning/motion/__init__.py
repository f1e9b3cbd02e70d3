"""Motion planning of the pick-flip-place cycle: cell, trajectories, collision checks, time and energy."""

from planning.interfaces import MotionPlanner, MotionRefused
from planning.motion.cell import CellLayout, carry_height_m
from planning.motion.energy import DynamicsEnergyModel, EnergyBreakdown, thesis_energy_j
from planning.motion.errors import InvalidCell
from planning.motion.move_cost import DynamicsMoveCost
from planning.motion.planner import CyclePlanner
from planning.motion.trajectory import JointPath, plan_path

__all__ = [
    "CellLayout",
    "CyclePlanner",
    "DynamicsEnergyModel",
    "DynamicsMoveCost",
    "EnergyBreakdown",
    "InvalidCell",
    "JointPath",
    "MotionPlanner",
    "MotionRefused",
    "carry_height_m",
    "plan_path",
    "thesis_energy_j",
]
