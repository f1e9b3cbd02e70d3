"""Placement planning: where each mug goes on the tray (2D packing under preferences), and in which order.

Every method of the thesis (§4.2: packing heuristics, SA, GA, PSOp, PSOk, best heuristic) plus an exact CP-SAT
model that proves the largest number of mugs that fit, and ``auto``, which combines them within a time budget.
"""

from planning.placement.context import PlanOptions
from planning.placement.cost import MoveCost, ThesisMoveCost
from planning.placement.datasets import cell_dataset_problem, dataset_problem
from planning.placement.errors import InvalidProblem
from planning.placement.planner import METHODS, PlacedMug, PlanResult, plan
from planning.placement.problem import FOOTPRINTS, CounterMug, MugType, Problem, TrayMug, TrayStray
from planning.placement.seam import PlacementPlanner

__all__ = [
    "FOOTPRINTS",
    "METHODS",
    "CounterMug",
    "InvalidProblem",
    "MoveCost",
    "MugType",
    "PlacedMug",
    "PlacementPlanner",
    "PlanOptions",
    "PlanResult",
    "Problem",
    "ThesisMoveCost",
    "TrayMug",
    "TrayStray",
    "cell_dataset_problem",
    "dataset_problem",
    "plan",
]
