"""The pytest plugin dishbot ships: registered as a ``pytest11`` entry point, and the README's example test
runs as written."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_example() -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Replaying sessions in your tests", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the README's replay section lost its example"
    return str(blocks[0])


def test_the_plugin_is_an_entry_point_of_the_installed_package() -> None:
    plugins = {e.name: e.value for e in entry_points(group="pytest11")}
    assert plugins.get("dishbot") == "replay.pytest_plugin"


def test_loading_the_plugin_imports_nothing_heavy() -> None:
    # pytest loads the entry point in every environment where dishbot is installed: it must cost nothing
    # until a test uses the fixture.
    heavy = ["zenoh", "numpy", "scipy", "pinocchio", "mujoco", "cv2", "mcap", "daemon", "recorder"]
    code = (
        "import json, sys; import replay.pytest_plugin; "
        f"print(json.dumps([m for m in {heavy!r} if m in sys.modules]))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == []


@pytest.mark.slow
def test_the_readme_example_is_ten_lines_and_passes(pytester: pytest.Pytester) -> None:
    example = readme_example()
    assert len([line for line in example.splitlines() if line.strip()]) <= 10
    pytester.makepyfile(test_readme_example=example)
    # The plugin by module name (a fresh checkout may not have been installed again since the entry point
    # was added; the entry-point test above checks the packaging).
    result = pytester.runpytest_inprocess("-p", "no:dishbot", "-p", "replay.pytest_plugin", "-q")
    result.assert_outcomes(passed=1)
