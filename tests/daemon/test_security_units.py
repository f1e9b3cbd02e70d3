"""The router's systemd unit: a notify service with a command line the CLI accepts, hardened, no devices."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from cli.main import build_parser
from tests.daemon.test_service_unit import parse_unit, seconds

ROUTER_UNIT = Path(__file__).resolve().parents[2] / "systemd" / "dishbot-router.service"


@pytest.fixture(scope="module")
def router_service() -> dict[str, list[str]]:
    return parse_unit(ROUTER_UNIT.read_text())["Service"]


def test_the_router_unit_runs_dishbot_router_with_the_system_config(
    router_service: dict[str, list[str]],
) -> None:
    (exec_start,) = router_service["ExecStart"]
    args = build_parser().parse_args(exec_start.split()[1:])
    assert (args.command, str(args.config)) == ("router", "/etc/dishbot/router.toml")
    assert not args.insecure
    assert router_service["Type"] == ["notify"]
    assert 2.0 <= seconds(router_service["WatchdogSec"][0]) <= 60.0
    assert router_service["Restart"] == ["on-failure"]


def test_the_router_unit_is_hardened_and_sees_no_devices(router_service: dict[str, list[str]]) -> None:
    assert router_service["PrivateDevices"] == ["yes"]
    assert router_service["NoNewPrivileges"] == ["yes"]
    assert router_service["CapabilityBoundingSet"] == [""]
    assert router_service["ProtectSystem"] == ["strict"]
    assert "DeviceAllow" not in router_service


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
@pytest.mark.slow
def test_systemd_accepts_every_directive_of_the_router_unit(tmp_path: Path) -> None:
    unit = tmp_path / "dishbot-router.service"
    unit.write_text(
        re.sub(r"^ExecStart=\S+", "ExecStart=/bin/true", ROUTER_UNIT.read_text(), flags=re.MULTILINE)
    )
    result = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=30, check=False
    )
    assert (result.returncode, result.stderr) == (0, "")
