"""The simulated cell's physical world on MuJoCo: scene, arm, physics, depth camera, collision accounting.

MuJoCo picks its OpenGL backend when it is first imported; without a display the only working choice here is
offscreen EGL, so it is the default for every process that loads the simulated world (set ``MUJOCO_GL`` to
``osmesa`` or ``glfw`` to override).
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
