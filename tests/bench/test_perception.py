"""``dishbot bench perception`` runs end to end and reports every column and target."""

from __future__ import annotations

import json

import pytest

from cli.main import main


def test_bench_perception_scores_one_frame_per_dataset(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "perception", "--frames", "1", "--seed", "7", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [r["dataset"] for r in doc["rows"]] == [1, 2, 3]
    assert [r["mugs"] for r in doc["rows"]] == [12, 12, 12]
    assert (doc["precision"], doc["recall"], doc["type_accuracy"]) == (1.0, 1.0, 1.0)
    assert doc["centre_error_median_mm"] < 3.0
    assert set(doc["targets_met"]) == {
        "precision>=0.99",
        "recall>=0.99",
        "centre_median<=3mm",
        "type_accuracy=100%",
        "time<=50ms",
    }


def test_bench_perception_refuses_zero_frames(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "perception", "--frames", "0"]) == 2
    assert capsys.readouterr().err == "dishbot bench: error: --frames 0: use 1 to 1000\n"
