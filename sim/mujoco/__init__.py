"""The simulated cell's physical world on MuJoCo: scene, arm, physics, depth camera, collision accounting.

MuJoCo's OpenGL backend defaults to offscreen EGL (``sim/__init__``: every module of ``sim``, the rig's
included, comes after it).
"""
