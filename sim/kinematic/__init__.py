"""The kinematic cell: the fast simulated work cell, a world without dynamics behind the real drivers.

``start_kinematic_cell`` builds the world and opens the same device simulators and drivers as the MuJoCo cell
on it; mugs and the tray come from the caller (the daemon sets them from a placement dataset or a ``start``
command).
"""

from sim.kinematic.cell import KinematicCell, start_kinematic_cell, visible_mugs
from sim.kinematic.devices import KinematicPlant
from sim.kinematic.world import KinematicWorld, MugGeometry, SimMug

__all__ = [
    "KinematicCell",
    "KinematicPlant",
    "KinematicWorld",
    "MugGeometry",
    "SimMug",
    "start_kinematic_cell",
    "visible_mugs",
]
