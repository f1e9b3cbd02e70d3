"""``dishbot bench daemon`` runs end to end and reports every measure (the numbers are not judged here)."""

from __future__ import annotations

import json

import pytest

from cli.main import main


@pytest.mark.slow
def test_bench_daemon_reports_every_measure_as_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(["bench", "daemon", "--commands", "10", "--seconds", "1", "--messages", "1000", "--json"]) == 0
    )
    doc = json.loads(capsys.readouterr().out)
    measures = {row["measure"]: row for row in doc["rows"]}
    assert list(measures) == [
        "command round trip (status)",
        "state publish -> receive",
        "joints publish -> receive",
        "event loop period error at 50 Hz, JSON channels only",
        "event loop period error at 50 Hz, + Foxglove channels",
        "event loop period error at 50 Hz, + live server, 1 client",
        "same, bare loop in another process",
    ]
    assert measures["command round trip (status)"]["samples"] == 10
    assert all(row["p50"] <= row["p99"] <= row["max"] for row in doc["rows"])
    assert doc["recording_messages_per_s"] > 0
    assert doc["recording_messages_per_s_with_foxglove"] > 0
    sizes = doc["job_file_kb_per_min"]
    assert list(sizes) == ["JSON channels only", "+ Foxglove channels", "+ live server, 1 client"]
    assert all(size > 0 for size in sizes.values())  # per minute: how big depends on the machine's load
    # The Foxglove channels are recorded where they are asked for, and only there (what, not how much:
    # the sizes per minute move with the machine's load).
    foxglove = doc["job_file_foxglove_channels"]
    assert list(foxglove) == list(sizes)
    assert foxglove["JSON channels only"] == 0
    assert foxglove["+ Foxglove channels"] > 0
    assert foxglove["+ live server, 1 client"] > 0
    assert doc["live_client_messages_per_s"] > 0  # the client received the served channels


def test_bench_daemon_refuses_a_silly_size(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "daemon", "--commands", "3"]) == 2
    assert capsys.readouterr().err == "dishbot bench: error: --commands 3: choose 10-100000\n"
