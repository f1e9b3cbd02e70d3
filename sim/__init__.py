"""The simulated worlds: everything that stands in for the physical cell.

``kinematic`` is the fast placeholder cell (no physics, devices as Python objects); ``mujoco`` is the
physical cell (MuJoCo scene, arm, depth camera, contacts) behind the byte-level device simulators of
``drivers.sim``; ``counter`` sets a dataset's mugs out on the counter; ``truth`` and ``scoring`` read the
ground truth and score perception against it. This layer sits above drivers, perception and planning (it
builds worlds from their parts) and below the daemon, which wires a world in for ``run --sim``.
"""
