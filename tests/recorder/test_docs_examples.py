"""The replay example in docs/recording.md runs as written against a real recording."""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "recording.md"


def replay_example() -> str:
    section = DOC.read_text().split("### Rewriting input streams (`replay.streams`)", 1)[1]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert blocks, "docs/recording.md lost its replay example"
    return str(blocks[0])


def test_replay_example_in_the_docs_runs(
    make_recording: Callable[..., Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    shutil.copy(make_recording("recorded.mcap", seconds=4.0), tmp_path / "session.mcap")
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    exec(compile(replay_example(), str(DOC), "exec"), namespace)
    faulted = namespace["faulted"]
    force = namespace["force"]
    assert faulted.end_s == 3.5  # type: ignore[attr-defined]
    assert force.holding()  # type: ignore[attr-defined]
    assert force.latest().t == pytest.approx(1.481)  # type: ignore[attr-defined]
    assert "drop force [1.5, 2) s" in capsys.readouterr().out
