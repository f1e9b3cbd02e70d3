"""The simulated worlds: everything that stands in for the physical cell.

``kinematic`` is the fast cell (no physics) and ``mujoco`` the physical one (MuJoCo scene, arm, depth
camera, contacts), both behind the byte-level device simulators of ``drivers.sim`` and the real drivers
(``devices``); ``counter`` sets a dataset's mugs out on the counter; ``truth`` and ``scoring`` read the
ground truth and score perception against it. This layer sits above drivers, perception and planning (it
builds worlds from their parts) and below the daemon, which wires a world in for ``run --sim``.
"""

import os

# MuJoCo picks its OpenGL backend when it is first imported; without a display the only working choice here is
# offscreen EGL, so it is the default for every process that loads a simulated world, whichever module of this
# package imports MuJoCo first (``sim.rig`` does so before ``sim.mujoco``). Set ``MUJOCO_GL`` to ``osmesa`` or
# ``glfw`` to override. ``cli.main`` sets the same default for verbs that load MuJoCo before ``sim``.
os.environ.setdefault("MUJOCO_GL", "egl")
