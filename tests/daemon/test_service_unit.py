"""The systemd unit asks for notify, watchdog and a clean stop, and still lets the daemon reach devices."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from cli.main import build_parser

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "dishbot.service"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Sections of a systemd unit with every value of each key in order (systemd allows repeats)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        key, sep, value = line.partition("=")
        assert sep, f"line {number} is neither a section, a comment nor KEY=VALUE: {raw!r}"
        assert current is not None, f"line {number} comes before any section"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


def seconds(value: str) -> float:
    """A systemd time span such as ``45s``, ``2min`` or ``1min 30s`` in seconds."""
    units = {"": 1.0, "s": 1.0, "sec": 1.0, "min": 60.0, "m": 60.0, "ms": 1e-3, "h": 3600.0}
    total = 0.0
    for number, unit in re.findall(r"(\d+(?:\.\d+)?)\s*([a-z]*)", value):
        total += float(number) * units[unit]
    return total


@pytest.fixture(scope="module")
def service() -> dict[str, list[str]]:
    return parse_unit(UNIT.read_text())["Service"]


def one(service: dict[str, list[str]], key: str) -> str:
    values = service.get(key, [])
    assert len(values) == 1, f"{key} should be set exactly once, found {values}"
    return values[0]


def test_unit_is_a_notify_service_with_a_watchdog_and_restart_on_failure(
    service: dict[str, list[str]],
) -> None:
    assert one(service, "Type") == "notify"
    assert one(service, "NotifyAccess") == "main"
    assert 2.0 <= seconds(one(service, "WatchdogSec")) <= 60.0
    assert one(service, "Restart") == "on-failure"


def test_stop_timeout_leaves_time_to_stop_the_arm_and_finish_the_recording(
    service: dict[str, list[str]],
) -> None:
    assert seconds(one(service, "TimeoutStopSec")) >= 30.0
    assert one(service, "KillMode") in {"mixed", "control-group"}
    assert "KillSignal" not in service or one(service, "KillSignal") in {"SIGTERM", "SIGINT"}


def test_unit_runs_the_hardware_daemon_from_the_system_config(service: dict[str, list[str]]) -> None:
    command = one(service, "ExecStart").split()
    assert command[0].startswith("/")
    assert Path(command[0]).name == "dishbot"
    assert command[1:] == ["run", "--config", "/etc/dishbot/dishbot.toml"]
    assert one(service, "ConfigurationDirectory") == "dishbot"


def test_the_unit_command_line_is_one_the_cli_accepts(service: dict[str, list[str]]) -> None:
    args = build_parser().parse_args(one(service, "ExecStart").split()[1:])
    assert args.command == "run"
    assert str(args.config) == "/etc/dishbot/dishbot.toml"
    assert not args.sim  # the backend comes from the config file: hardware on the robot


def test_dedicated_user_keeps_the_serial_ports_and_camera_reachable(service: dict[str, list[str]]) -> None:
    assert one(service, "User") == "dishbot"
    assert "dialout" in one(service, "SupplementaryGroups").split()
    assert service.get("PrivateDevices", ["no"]) == ["no"]
    allowed = {tuple(v.split()) for v in service["DeviceAllow"]}
    assert {("char-ttyUSB", "rw"), ("char-ttyACM", "rw"), ("char-video4linux", "rw")} <= allowed
    assert one(service, "StateDirectory") == "dishbot"


def test_unit_is_hardened(service: dict[str, list[str]]) -> None:
    assert one(service, "NoNewPrivileges") == "yes"
    assert one(service, "ProtectSystem") == "strict"
    assert one(service, "ProtectHome") == "yes"
    assert one(service, "CapabilityBoundingSet") == ""
    assert one(service, "DevicePolicy") == "closed"
    assert "AF_PACKET" not in one(service, "RestrictAddressFamilies")


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
@pytest.mark.slow
def test_systemd_accepts_every_directive(tmp_path: Path) -> None:
    # verify needs an executable that exists; everything else is checked as installed.
    unit = tmp_path / "dishbot.service"
    text = UNIT.read_text()
    unit.write_text(re.sub(r"^ExecStart=\S+", "ExecStart=/bin/true", text, flags=re.MULTILINE))
    result = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=30, check=False
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
