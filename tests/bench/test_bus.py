"""`dishbot bench bus` runs end to end and reports every metric (values are checked by people, not here)."""

from __future__ import annotations

import json

import pytest

from cli.main import main


@pytest.mark.slow
@pytest.mark.xdist_group("realtime-pty")  # its pseudo-terminal bus answers in real time: one at a time
def test_bench_bus_reports_every_metric_as_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "bus", "--seconds", "0.3", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    metrics = {row["metric"]: row["value"] for row in doc["rows"]}
    assert doc["benchmark"] == "bench bus"
    assert metrics["bus cycle rate, Protocol 1.0, 6 servos"] > 0
    assert metrics["bus cycle rate, Protocol 2.0, 6 servos"] > 0
    assert metrics["control loop rate (arm.follow)"] > 0
    assert "event-loop jitter p99, bus at 50 Hz" in metrics
    assert doc["jitter_samples"] > 0
