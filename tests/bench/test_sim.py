"""``dishbot bench sim``: bad flags are refused in one clear line; the counter setup it runs on."""

from __future__ import annotations

import pytest

from bench.sim import MujocoCounter, catalogue_of, layout_of
from daemon.cli import main
from daemon.clock import SimulatedClock
from daemon.config import load_config
from sim.mujoco.cell import open_sim_cell


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--datasets", "4"], "--datasets: unknown dataset '4' (the simulated cell runs 1, 2 and 3)"),
        (["--datasets", ","], "--datasets: name at least one of 1, 2, 3"),
        (["--timeout", "0"], "--timeout: 0.0 must be > 0 seconds"),
        (["--fsr-debounce", "-1"], "--fsr-debounce: -1.0 must be in [0, 1] seconds"),
    ],
)
def test_bad_flags_exit_2_with_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "sim", *argv]) == 2
    assert capsys.readouterr().err == f"dishbot bench: error: {message}\n"


def test_counter_puts_a_dataset_on_the_cell_and_refuses_the_full_size_tray() -> None:
    config = load_config()
    clock = SimulatedClock()

    async def body() -> None:
        async with open_sim_cell(layout_of(config), [], clock=clock) as cell:
            counter = MujocoCounter(cell, config)
            tray = counter.set_counter(dataset=2, mugs=None)
            assert tray.origin_m == config.cell.tray_origin_m
            kinds = sorted(m.spec.name for m in cell.mugs)
            assert kinds == ["big"] * 8 + ["small"] * 4
            assert set(cell.world.mug_truths()) == {m.mug_id for m in cell.mugs}
            assert catalogue_of(config)["big"].diameter_mm == 91
            with pytest.raises(ValueError, match=r"^dataset 4 needs the full-size tray"):
                counter.set_counter(dataset=4, mugs=None)

    clock.run(body())
