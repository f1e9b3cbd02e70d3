"""The console examples in docs/arm.md run and print what the page shows."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from cli.main import main

DOC = Path(__file__).parents[3] / "docs" / "arm.md"
BLOCK = re.compile(r"```console\n(.*?)```", re.DOTALL)


def _examples() -> list[tuple[list[str], str]]:
    out = []
    for block in BLOCK.findall(DOC.read_text(encoding="utf-8")):
        first, _, rest = block.partition("\n")
        assert first.startswith("$ dishbot ")
        out.append((shlex.split(first[2:])[1:], rest))
    return out


def _pairs(path: Path) -> None:
    rng = np.random.default_rng(0)
    commanded = np.column_stack(
        [rng.uniform(0.35, 0.6, 20), rng.uniform(0.0, 0.4, 20), rng.choice([0.06, 0.2], 20)]
    )
    pairs = [{"commanded": list(c), "reached": list(c + 0.003)} for c in commanded]
    path.write_text(json.dumps({"pairs": pairs}), encoding="utf-8")


@pytest.mark.parametrize(
    ("argv", "expected"), _examples(), ids=lambda v: " ".join(v) if isinstance(v, list) else ""
)
@pytest.mark.slow
def test_console_example_prints_what_the_docs_show(
    argv: list[str],
    expected: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    _pairs(tmp_path / "pairs.json")
    code = main(argv)
    out = capsys.readouterr().out
    if expected:
        shown = expected.splitlines()
        assert out.splitlines()[: len(shown)] == shown
    assert code == (1 if '"ok": false' in expected else 0)
