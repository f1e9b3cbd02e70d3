"""The one backend builder (``daemon.cell.open_backend``): ``dishbot run`` and ``dishbot bench sim`` ask it
for the same cell, every cell it builds takes the configured start pose, arm calibration and mug catalogue,
a full-size-tray dataset gets the one refusal on every path, and the hardware backend loads no simulator."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import daemon.cell
from cli.main import main
from daemon.backend import Backend, SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import Config, load_config
from daemon.errors import UsageError
from daemon.job import CommandRefused, Job, StartRequest
from description.thesis import MugSpec
from perception import CameraObserver, associate
from planning.arm.calibration import PositionCorrection
from wire.messages import HeaderScene, UnsetType, header_part

FULL_TRAY_REFUSAL = (
    "dataset 4 needs the full-size tray (475 x 520 mm), which the MuJoCo cell does not have (its tray is "
    "the configured 332 x 374 mm one); use dataset 1, 2, 3 or the kinematic cell"
)
START_Q = [0.3, -1.4, 2.0, 1.0, -1.5708]
MEDIUM = MugSpec("medium", diameter_mm=82, width_mm=110, height_mm=95, mass_kg=0.15)


def _config(tmp_path: Path) -> tuple[Config, PositionCorrection]:
    """A config that differs from the defaults in all three drifted parts: start pose, arm calibration and
    catalogue (a third mug type)."""
    correction = PositionCorrection(((0.001,) + (0.0,) * 6, (0.0,) * 7, (-0.002,) + (0.0,) * 6))
    path = tmp_path / "arm.json"
    path.write_text(json.dumps(correction.to_mapping()))
    medium = {k: getattr(MEDIUM, k) for k in ("diameter_mm", "width_mm", "height_mm", "mass_kg")}
    config = load_config(
        overrides={
            "sim": {"start_q_rad": START_Q},
            "arm": {"calibration_file": str(path)},
            "mug_types": {"medium": medium},
        }
    )
    return config, correction


def test_run_and_bench_sim_ask_the_one_builder_for_the_same_cell(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    asked: list[tuple[Config, SimOptions | None]] = []

    async def spy(
        config: Config, *, sim: SimOptions | None = None, clock: Any = None, executor: Any = None
    ) -> Backend:
        asked.append((config, sim))
        raise UsageError("stop here")

    # Both verbs import the builder when they run, so the one spy on its home module sees both.
    monkeypatch.setattr(daemon.cell, "open_backend", spy)
    path = tmp_path / "robot.toml"
    path.write_text(
        "[sim]\nstart_q_rad = [0.3, -1.4, 2.0, 1.0, -1.5708]\n[mug_types.medium]\n"
        "diameter_mm = 62\nwidth_mm = 86\nheight_mm = 66\nmass_kg = 0.08\n"
    )
    run = ["run", "--sim", "--world", "mujoco", "--dataset", "2", "--once", "--config", str(path)]
    assert main([*run, "--record-dir", str(tmp_path)]) == 2
    assert main(["bench", "sim", "--datasets", "2", "--config", str(path)]) == 2
    (run_config, run_sim), (bench_config, bench_sim) = asked
    assert run_config == bench_config
    assert run_config.sim.start_q_rad == tuple(START_Q)
    assert run_sim == bench_sim == SimOptions(world="mujoco", dataset=2)


async def _open_and_check(config: Config, correction: PositionCorrection, world: str) -> Backend:
    backend = await open_backend(config, sim=SimOptions(world=world, dataset=1))
    joints = await backend.arm.read_joints()
    np.testing.assert_allclose(joints.position_rad, START_Q, atol=0.02)
    assert getattr(backend.motion, "correction") == correction  # noqa: B009
    assert getattr(backend.motion, "catalogue") == config.mug_catalogue()  # noqa: B009
    assert backend.tray == config.cell.tray
    return backend


def test_the_kinematic_cell_takes_the_configured_start_pose_calibration_and_catalogue(tmp_path: Path) -> None:
    config, correction = _config(tmp_path)

    async def body() -> None:
        backend = await _open_and_check(config, correction, "kinematic")
        await backend.close()

    asyncio.run(body())


@pytest.mark.slow
def test_the_mujoco_cell_takes_them_too_and_refuses_a_full_size_tray_dataset_on_start(tmp_path: Path) -> None:
    config, correction = _config(tmp_path)

    async def body() -> None:
        backend = await _open_and_check(config, correction, "mujoco")
        try:
            assert isinstance(backend.observer, CameraObserver)
            assert backend.observer.detector.catalogue == config.mug_catalogue()
            assert backend.observer.detector.catalogue["medium"] == MEDIUM
            job = Job(backend, config, lambda key, payload: None, associate)
            control = asyncio.create_task(job.run())
            with pytest.raises(CommandRefused) as info:
                await job.command("start", StartRequest(dataset=4))
            assert str(info.value) == FULL_TRAY_REFUSAL
            assert job.chart.state == "idle"
            await job.shutdown()
            control.cancel()
        finally:
            await backend.close()

    asyncio.run(body())


def test_a_full_size_tray_dataset_gets_the_one_refusal_from_run_and_bench(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = ["run", "--sim", "--world", "mujoco", "--dataset", "4", "--once", "--record-dir", str(tmp_path)]
    assert main(run) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"dishbot run: error: {FULL_TRAY_REFUSAL}"
    assert main(["bench", "sim", "--datasets", "1,4"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"dishbot bench: error: {FULL_TRAY_REFUSAL}"
    assert not list(tmp_path.glob("*.mcap"))  # refused before anything started


def test_the_kinematic_cell_sets_a_full_size_tray_dataset_out_on_its_own_tray() -> None:
    config = load_config()
    clock = SimulatedClock()

    async def body() -> None:
        backend = await open_backend(config, sim=SimOptions(world="kinematic", dataset=4), clock=clock)
        assert backend.tray.size_mm == (475, 520)
        assert backend.counter is not None
        assert len(backend.counter.scene()["mugs"]) == 30  # type: ignore[arg-type]
        await backend.close()

    clock.run(body())


@pytest.mark.parametrize("dataset", [2, 4])
def test_the_kinematic_cell_s_header_scene_reads_through_its_view_with_dataset_and_tray(dataset: int) -> None:
    """The header's scene is the backend's, overridden by the kinematic world's own (its tray in m): the view
    the replay and the recorder read it through keeps the dataset and the tray. (A view that did not fit
    read as empty: every kinematic recording of a dataset other than 1 replayed in a dataset-1 stand-in.)"""
    config = load_config()
    clock = SimulatedClock()

    async def body() -> None:
        backend = await open_backend(config, sim=SimOptions(world="kinematic", dataset=dataset), clock=clock)
        scene = backend.scene()
        await backend.close()
        view = header_part(scene, HeaderScene)
        assert view.dataset == dataset
        assert view.backend == backend.name
        assert not isinstance(view.tray, UnsetType)
        assert view.tray.size_mm_of() == pytest.approx(backend.tray.size_mm)

    clock.run(body())


_HARDWARE_ONLY = """
import asyncio, json, sys
from daemon.cell import open_backend
from tests.fakes.hw_rig import rig

async def main():
    with rig() as r:
        backend = await open_backend(r.config)
        await backend.close()

asyncio.run(main())
simulation = ("mujoco", "sim", "daemon.sim_backend")
loaded = [m for m in sys.modules if m in simulation or m.startswith(("mujoco.", "sim."))]
print(json.dumps(sorted(loaded)))
"""


@pytest.mark.slow
def test_the_hardware_backend_loads_neither_the_simulated_worlds_nor_mujoco() -> None:
    root = Path(__file__).parents[2]
    done = subprocess.run(
        [sys.executable, "-c", _HARDWARE_ONLY],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []
