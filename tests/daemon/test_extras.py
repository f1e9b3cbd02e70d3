"""A plain install (no extras) runs the hardware daemon; a verb that needs an extra says which, in one line.

The missing library is simulated in a fresh interpreter with ``sys.modules[name] = None``, which makes its
import fail exactly as when it is not installed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cli.extras import missing_extra
from daemon.config import to_toml
from tests.daemon.conftest import free_port
from tests.fakes.hw_rig import rig

NO_SIM = "dishbot {verb}: error: the MuJoCo cell needs the 'sim' extra: pip install 'dishbot[sim]'"


def run_without(module: str, *argv: str) -> subprocess.CompletedProcess[str]:
    """``dishbot ARGV`` in a fresh interpreter where importing ``module`` fails as if it was not installed."""
    code = (
        f"import sys; sys.modules[{module!r}] = None\n"
        "from cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120, check=False
    )


@pytest.mark.slow
def test_run_on_the_mujoco_cell_without_the_sim_extra_names_the_extra(tmp_path: Path) -> None:
    proc = run_without(
        "mujoco",
        *("run", "--sim", "--world", "mujoco", "--once", "--record-dir", str(tmp_path)),
        *("--listen", f"tcp/127.0.0.1:{free_port()}"),
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == NO_SIM.format(verb="run")
    assert "Traceback" not in proc.stderr
    assert list(tmp_path.iterdir()) == []  # refused before the daemon started: no recording
    assert proc.stdout == ""


@pytest.mark.parametrize("bench", ["sim", "perception"])
@pytest.mark.slow
def test_the_mujoco_benchmarks_without_the_sim_extra_name_the_extra(bench: str) -> None:
    proc = run_without("mujoco", "bench", bench, "--datasets" if bench == "sim" else "--frames", "1")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == NO_SIM.format(verb="bench")
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_the_hardware_daemon_runs_a_job_without_mujoco(tmp_path: Path) -> None:
    """``dishbot run`` on the hardware backend, on the simulated devices' pseudo-terminals, with MuJoCo
    impossible to import: the robot's code path needs nothing of the ``sim`` extra."""
    with rig() as r:
        config = tmp_path / "robot.toml"
        config.write_text(to_toml(r.config.to_dict()), encoding="utf-8")
        proc = run_without(
            "mujoco",
            *("run", "--once", "--config", str(config), "--record-dir", str(tmp_path)),
            *("--listen", f"tcp/127.0.0.1:{free_port()}"),
        )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0] == "job ended in state done"
    assert len(list(tmp_path.glob("*.mcap"))) == 1


@pytest.mark.slow
def test_a_missing_core_library_keeps_its_traceback() -> None:
    """OR-Tools is a core dependency: its absence is a broken install, not a missing extra, so it is not
    dressed up as one."""
    proc = run_without("ortools", "plan", "--dataset", "1", "--method", "exact")
    assert proc.returncode == 1
    assert "Traceback" in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last == "ModuleNotFoundError: No module named 'ortools.sat'; 'ortools' is not a package"


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("mujoco", "the MuJoCo cell needs the 'sim' extra: pip install 'dishbot[sim]'"),
        ("mujoco.viewer", "the MuJoCo cell needs the 'sim' extra: pip install 'dishbot[sim]'"),
        ("mujoco_mjx", None),
        ("scipy", None),
        (None, None),
    ],
)
def test_only_the_libraries_of_an_extra_get_the_extras_message(name: str | None, message: str | None) -> None:
    assert missing_extra(ModuleNotFoundError("no module", name=name)) == message
