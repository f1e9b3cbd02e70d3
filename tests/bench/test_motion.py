"""``dishbot bench motion``: the table's rows and JSON document, and its bad input."""

from __future__ import annotations

import json

import pytest

from cli.main import main


@pytest.mark.slow
def test_bench_motion_json_reports_ik_trajectories_and_the_dataset_cycle(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["bench", "motion", "--samples", "10", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = {r["metric"]: r for r in doc["rows"]}
    assert rows["IK success (position)"]["value"] == 100
    assert rows["IK success (side grasp)"]["value"] == 100
    assert rows["IK residual max (side grasp)"]["value"] <= 1.0
    assert rows["mugs moved (dataset 1)"]["value"] >= 8
    assert 10 < rows["cycle time per mug (mean)"]["value"] < 180
    dyn = rows["energy per mug, dynamics, with standby"]["value"]
    assert (
        dyn
        > rows["energy per mug, dynamics, motion"]["value"]
        > rows["energy per mug, thesis proxy M g dm"]["value"]
    )
    assert doc["dataset"] == 1


def test_bench_motion_on_the_full_size_tray_reports_how_long_a_refused_slot_takes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["bench", "motion", "--samples", "10", "--dataset", "4", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = {r["metric"]: r for r in doc["rows"]}
    assert rows["mugs moved (dataset 4)"]["value"] >= 1
    assert rows["slots refused (dataset 4)"]["value"] == len(doc["refused"]) >= 1
    cpu = rows["refused slot CPU time p50"]["value"]
    assert 0 < cpu <= rows["refused slot CPU time max"]["value"]
    assert rows["refused slot p50"]["unit"] == "s"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--dataset", "7"], "--dataset: expected a thesis dataset, 1 to 6, got '7'"),
        (["--samples", "5"], "--samples: expected a whole number, at least 10, got '5'"),
    ],
)
def test_bench_motion_bad_input_exits_2(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    assert main(["bench", "motion", *argv]) == 2
    assert capsys.readouterr().err == f"dishbot bench: error: {message}\n"
