"""The [recording] and [foxglove] config tables: defaults, and each bad value refused naming its field."""

from __future__ import annotations

import tomllib
from typing import Any

import pytest

from daemon.config import load_config, parse_config, to_toml
from daemon.errors import ConfigError


def test_defaults_compress_rotate_keep_limits_and_serve_nothing_live() -> None:
    c = load_config()
    assert (c.recording.compression, c.recording.idle_telemetry_hz, c.recording.idle_file_s) == (
        "zstd",
        1.0,
        3600.0,
    )
    assert (c.recording.max_total_mb, c.recording.max_age_days, c.recording.job_tail_s) == (5000, 30.0, 2.0)
    assert (c.foxglove.channels, c.foxglove.listen, c.foxglove.insecure) == (True, "", False)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_the_config_round_trips_through_config_show(compression: str) -> None:
    c = load_config(
        overrides={"recording": {"compression": compression}, "foxglove": {"listen": "[::1]:8765"}}
    )
    assert parse_config(tomllib.loads(to_toml(c.to_dict()))) == c
    assert c.recording.compression == (None if compression == "none" else compression)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            {"recording": {"compression": "gzip"}},
            "recording.compression: 'gzip' is not one of zstd, lz4, none",
        ),
        (
            {"recording": {"idle_telemetry_hz": 0}},
            "recording.idle_telemetry_hz: 0 is out of range; allowed [0.01, 100]",
        ),
        (
            {"recording": {"idle_file_s": 1.0}},
            "recording.idle_file_s: 1 is out of range; allowed [10, 604800]",
        ),
        ({"recording": {"job_tail_s": -1}}, "recording.job_tail_s: -1 is out of range; allowed [0, 60]"),
        (
            {"recording": {"max_total_mb": 1.5}},
            "recording.max_total_mb: expected an integer in [0, 10000000], got 1.5",
        ),
        (
            {"recording": {"max_age_days": "a"}},
            "recording.max_age_days: expected a number in [0, 3650], got 'a'",
        ),
        (
            {"recording": {"rotate": True}},
            "recording.rotate: unknown key in recording (known keys: chunk_size_bytes, compression, dir, "
            "idle_file_s, idle_telemetry_hz, job_tail_s, max_age_days, max_total_mb)",
        ),
        ({"foxglove": {"channels": "yes"}}, "foxglove.channels: expected true or false, got 'yes'"),
        ({"foxglove": {"depth_hz": 100}}, "foxglove.depth_hz: 100 is out of range; allowed [0.01, 30]"),
        ({"foxglove": {"listen": 8765}}, "foxglove.listen: expected a string, got 8765"),
        (
            {"foxglove": {"listen": "localhost"}},
            "foxglove.listen: 'localhost' is not HOST:PORT like 127.0.0.1:8765 "
            "(IPv6 as [::1]:8765; port 0-65535)",
        ),
        (
            {"foxglove": {"listen": "10.0.0.2:8765"}},
            "foxglove.listen: 10.0.0.2 is not a loopback address; the Foxglove server has no "
            "authentication, so it listens on 127.0.0.1 unless [foxglove] insecure = true",
        ),
    ],
)
def test_bad_values_are_refused_naming_the_field(overrides: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(overrides=overrides)
    assert str(err.value) == message
