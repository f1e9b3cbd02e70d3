"""The README's console examples run as written (``...`` stands for any text, or alone for any lines)."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).parents[1] / "README.md"


def console_examples() -> list[tuple[str, list[str]]]:
    """(command, expected output lines) for every ``$ dishbot ...`` line in the README's console blocks."""
    examples: list[tuple[str, list[str]]] = []
    for block in re.findall(r"```console\n(.*?)```", README.read_text(encoding="utf-8"), re.DOTALL):
        for line in block.splitlines():
            if line.startswith("$ "):
                examples.append((line[2:], []))
            elif examples:
                examples[-1][1].append(line)
    return examples


def matches(expected: list[str], actual: list[str]) -> bool:
    pattern = "\n".join(
        r"(?:.*\n?)*?" if line == "..." else ".*".join(map(re.escape, line.split("..."))) + r"\n?"
        for line in expected
    )
    return re.fullmatch(pattern, "\n".join(actual) + "\n") is not None


def test_the_readme_has_console_examples() -> None:
    assert len(console_examples()) >= 2


@pytest.mark.parametrize(("command", "expected"), console_examples())
@pytest.mark.slow
def test_readme_example_prints_what_the_readme_says(command: str, expected: list[str]) -> None:
    argv = shlex.split(command)
    assert argv[0] == "dishbot"
    out = subprocess.run(
        [sys.executable, "-m", "cli.main", "--log-level", "error", *argv[1:]],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    assert matches(expected, out.splitlines()), out
