"""The simulated worlds: everything that stands in for the physical cell.

``kinematic`` is the fast cell (no physics) and ``mujoco`` the physical one (MuJoCo scene, arm, depth
camera, contacts), both behind the byte-level device simulators of ``drivers.sim`` and the real drivers
(``devices``); ``counter`` sets a dataset's mugs out on the counter; ``truth`` and ``scoring`` read the
ground truth and score perception against it. This layer sits above drivers, perception and planning (it
builds worlds from their parts) and below the daemon, which wires a world in for ``run --sim``.
"""
