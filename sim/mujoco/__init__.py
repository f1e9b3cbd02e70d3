"""The simulated cell's physical world on MuJoCo: scene, arm, physics, depth camera, collision accounting.

MuJoCo's OpenGL backend is offscreen EGL unless ``MUJOCO_GL`` says otherwise: ``sim/__init__.py`` sets the
default, and it runs before any module of ``sim`` imports MuJoCo.
"""
