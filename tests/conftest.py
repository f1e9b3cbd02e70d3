"""Shared fixtures for the dishbot test suite."""

from __future__ import annotations

import os

# MuJoCo renders offscreen without a GPU through EGL (Mesa llvmpipe); set before any mujoco import.
os.environ.setdefault("MUJOCO_GL", "egl")
