"""The kinematic cell: a placeholder simulated work cell (no physics) behind the driver protocols.

``open_kinematic_cell`` builds the world and its devices; mugs and the tray come from the caller (the daemon
sets them from a placement dataset or a ``start`` command).
"""

from sim.kinematic.cell import KinematicCell, open_kinematic_cell
from sim.kinematic.devices import SimArm, SimForceSensor, SimGripper
from sim.kinematic.world import KinematicWorld, MugGeometry, SimMug

__all__ = [
    "KinematicCell",
    "KinematicWorld",
    "MugGeometry",
    "SimArm",
    "SimForceSensor",
    "SimGripper",
    "SimMug",
    "open_kinematic_cell",
]
