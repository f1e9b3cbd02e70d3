"""The statechart picture in the docs is the chart the code runs (regenerate with ``dishbot statechart``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from statechart.mermaid import to_mermaid

ROOT = Path(__file__).parents[2]


@pytest.mark.parametrize("doc", ["README.md", "docs/daemon.md"])
def test_the_documented_statechart_is_the_generated_one(doc: str) -> None:
    block = re.search(r"```mermaid\n(.*?)```", (ROOT / doc).read_text(encoding="utf-8"), re.DOTALL)
    assert block is not None
    assert block.group(1) == to_mermaid()
