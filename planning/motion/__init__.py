"""Motion planning of the pick-flip-place cycle: cell, trajectories, collision checks, time and energy."""

from planning.motion.cell import CellLayout, carry_height_m
from planning.motion.errors import InvalidCell, UnknownMugType

__all__ = ["CellLayout", "InvalidCell", "UnknownMugType", "carry_height_m"]
