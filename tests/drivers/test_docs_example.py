"""The example in docs/drivers.md runs as written against the simulators."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import structlog

DOC = Path(__file__).resolve().parents[2] / "docs" / "drivers.md"


@pytest.mark.slow
@pytest.mark.xdist_group("realtime-pty")  # simulators on pseudo-terminals in real time: one at a time
def test_the_drivers_readme_example_runs(capsys: pytest.CaptureFixture[str]) -> None:
    source = re.search(r"```python\n(.*?)```", DOC.read_text(), re.S)
    assert source is not None
    with structlog.testing.capture_logs() as logs:
        exec(compile(source.group(1), str(DOC), "exec"), {"__name__": "__main__"})
    assert capsys.readouterr().out.splitlines()[-1].startswith("False aperture 0.0")
    assert any(e["event"] == "grasp_missed" for e in logs)
