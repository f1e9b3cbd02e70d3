"""Fixtures for the recording, replay and service tests: small recordings built with the real Recorder."""

from __future__ import annotations

from pathlib import Path

import pytest

from recorder import Recorder


class RecordingFactory:
    """Builds finished recordings of a 50 Hz session: joints and force every 20 ms, observations at 2 Hz.

    Force is 2 N (a mug held) from sample 50 to 149 and 0.1 N otherwise; times start at ``t0_ns``.
    """

    t0_ns = 1_790_000_000_000_000_000  # a fixed wall-clock start, so times in assertions are exact

    def __init__(self, directory: Path) -> None:
        self.directory = directory

    def __call__(
        self,
        name: str = "session.mcap",
        *,
        seconds: float = 4.0,
        chunk_size: int = 4096,
        compression: str | None = None,
    ) -> Path:
        T0_NS = self.t0_ns
        path = self.directory / name
        with Recorder(path, chunk_size=chunk_size, compression=compression) as rec:
            rec.write_header(
                {"robot_id": "r1", "backend": "sim"},
                {"dataset": 1, "mugs": [{"id": "m0", "type": "big", "x_m": 0.1, "y_m": 0.3}]},
                log_time_ns=T0_NS,
            )
            for i in range(round(seconds * 50)):
                t_ns = T0_NS + i * 20_000_000
                t = i * 0.02
                rec.write(
                    "dishbot/r1/input/joints",
                    {
                        "t": t,
                        "names": ["j1", "j2"],
                        "position_rad": [0.01 * i, -0.5],
                        "velocity_rad_s": [0.5, 0.0],
                        "load": [0.1, 0.2],
                    },
                    log_time_ns=t_ns,
                )
                rec.write(
                    "dishbot/r1/input/force",
                    {
                        "t": t,
                        "force_n": 2.0 if 50 <= i < 150 else 0.1,
                        "raw": 400 if 50 <= i < 150 else 20,
                        "seq": i,
                    },
                    log_time_ns=t_ns + 1_000_000,
                )
                if i % 25 == 0:
                    rec.write(
                        "dishbot/r1/input/observation",
                        {
                            "t": t,
                            "meta": {},
                            "mugs": [
                                {
                                    "id": "m0",
                                    "type": "big",
                                    "x_m": 0.1,
                                    "y_m": 0.3 + 0.001 * i,
                                    "upside_down": False,
                                    "handle_yaw_rad": 1.5,
                                    "confidence": 0.9,
                                }
                            ],
                        },
                        log_time_ns=t_ns + 2_000_000,
                    )
        return path


@pytest.fixture
def make_recording(tmp_path: Path) -> RecordingFactory:
    return RecordingFactory(tmp_path)


@pytest.fixture
def t0_ns() -> int:
    return RecordingFactory.t0_ns
