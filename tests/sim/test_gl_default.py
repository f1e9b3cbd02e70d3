"""MuJoCo's OpenGL backend is offscreen EGL by default in every process that loads a simulated world or runs
a verb, whichever module imports MuJoCo first: without a display GLFW, MuJoCo's own default, cannot render
(``dishbot sim rig`` and ``dishbot bench perception`` failed so without ``MUJOCO_GL`` set)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow  # each starts a Python process


def _python(code: str, **env: str) -> str:
    """The last line ``code`` prints, run in a process without ``MUJOCO_GL`` unless ``env`` gives one."""
    base = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    done = subprocess.run(
        [sys.executable, "-c", code],
        env={**base, **env},
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    return done.stdout.strip().splitlines()[-1]


def test_the_rig_module_imports_mujoco_with_egl() -> None:
    # sim.rig imports MuJoCo before sim.mujoco, which used to set the default
    code = "import sim.rig, mujoco, os; print(os.environ['MUJOCO_GL'], mujoco.GLContext.__module__)"
    assert _python(code) == "egl mujoco.egl"


def test_a_verb_that_imports_mujoco_before_sim_gets_egl() -> None:
    code = (
        "from cli.main import main; main(['--log-level', 'error', 'plan', '--dataset', '3', '--footprint', "
        "'rect']); import mujoco; print(mujoco.GLContext.__module__)"
    )
    assert _python(code) == "mujoco.egl"


def test_a_backend_of_the_users_own_is_kept() -> None:
    code = (
        "import os, sim; from cli.main import main; main(['--log-level', 'error', 'plan', '--dataset', '3', "
        "'--footprint', 'rect']); print(os.environ['MUJOCO_GL'])"
    )
    assert _python(code, MUJOCO_GL="osmesa") == "osmesa"
