"""A replay plans with the settings the recording was made with, also where a default changed since."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pytest

from daemon.planners import cycle_planner
from planning.arm import ArmModel
from planning.motion.planner import CyclePlanner
from recorder import Recorder, read_messages
from replay.session import RecordedSession
from wire.schemas import HEADER_TOPIC

RIG_RECORDING = Path(__file__).parents[1] / "data" / "rig-2mugs-job.mcap"


def _copy_with_planner(
    target: Path, change: dict[str, object], drop: str | None, *, section: str = "planner"
) -> Path:
    messages = list(read_messages(RIG_RECORDING).messages)
    assert messages[0].topic == HEADER_TOPIC
    header = messages[0].payload

    def table(v: object) -> dict[str, object]:
        assert isinstance(v, Mapping)
        return dict(v)

    config = table(header["config"])
    planner = {**table(config[section]), **change}
    if drop is not None:
        planner.pop(drop, None)
    config[section] = planner
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


def test_a_recording_from_before_the_slow_set_down_replays_with_set_downs_at_fine_speed(
    tmp_path: Path,
) -> None:
    """``[arm] set_down_slow_m`` came with the slow last stretch of every set-down (0.03 m by default): a
    recording without it set its mugs down at fine speed all the way, and its replay plans them so."""
    path = _copy_with_planner(tmp_path / "old-job.mcap", {}, drop="set_down_slow_m", section="arm")
    assert RecordedSession.load(path).config.arm.set_down_slow_m == 0.0
    assert RecordedSession.load(RIG_RECORDING).config.arm.set_down_slow_m == 0.0  # made before it


@pytest.mark.parametrize("slow_m", [0.0, 0.02])
def test_a_recorded_set_down_is_the_replays(tmp_path: Path, slow_m: float) -> None:
    change: dict[str, object] = {"set_down_slow_m": slow_m, "set_down_speed_m_s": 0.02}
    path = _copy_with_planner(tmp_path / "job.mcap", change, drop=None, section="arm")
    config = RecordedSession.load(path).config
    assert (config.arm.set_down_slow_m, config.arm.set_down_speed_m_s) == (slow_m, 0.02)
    # ... and the cycle planner the replay builds from that config sets mugs down so.
    planner = cycle_planner(config, config.cell.tray, arm=ArmModel.load(), executor=None)
    assert isinstance(planner, CyclePlanner)
    settings = planner.scene.settings
    assert (settings.set_down_slow_m, settings.set_down_speed_m_s) == (slow_m, 0.02)
