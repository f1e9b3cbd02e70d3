"""A replay plans with the settings the recording was made with, also where a default changed since."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pytest

from recorder import Recorder, read_messages
from replay.session import RecordedSession
from wire.schemas import HEADER_TOPIC

RIG_RECORDING = Path(__file__).parents[1] / "data" / "rig-2mugs-job.mcap"


def _copy_with_planner(target: Path, change: dict[str, object], drop: str | None) -> Path:
    messages = list(read_messages(RIG_RECORDING).messages)
    assert messages[0].topic == HEADER_TOPIC
    header = messages[0].payload

    def table(v: object) -> dict[str, object]:
        assert isinstance(v, Mapping)
        return dict(v)

    config = table(header["config"])
    planner = {**table(config["planner"]), **change}
    if drop is not None:
        planner.pop(drop, None)
    config["planner"] = planner
    with Recorder(target, chunk_size=64 * 1024, lossless=True) as rec:
        rec.write_header(
            config,
            table(header["scene"]),
            log_time_ns=messages[0].log_time_ns,
            job=table(header.get("job")),
            file=table(header.get("file")),
            clock=table(header.get("clock")),
        )
        for m in messages[1:]:
            rec.write(m.topic, dict(m.payload), log_time_ns=m.log_time_ns)
    return target


def test_a_recording_from_before_the_footprint_setting_replays_with_rectangles(tmp_path: Path) -> None:
    """``[planner] footprint`` came with mug-shaped placement, whose default is now ``mug``: a recording
    without it was planned with rectangles, and its replay plans with them too."""
    old = RecordedSession.load(_copy_with_planner(tmp_path / "old-job.mcap", {}, drop="footprint"))
    assert old.config.planner.footprint == "rect"


@pytest.mark.parametrize("footprint", ["mug", "rect"])
def test_a_recorded_footprint_is_the_replays(tmp_path: Path, footprint: str) -> None:
    path = _copy_with_planner(tmp_path / "job.mcap", {"footprint": footprint}, drop=None)
    assert RecordedSession.load(path).config.planner.footprint == footprint
