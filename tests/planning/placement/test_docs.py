"""The examples in docs/placement.md (merged into the README) run as written."""

from __future__ import annotations

import json
import re
from pathlib import Path

from planning.placement import PlanOptions, Problem, plan

DOC = Path(__file__).resolve().parents[3] / "docs" / "placement.md"


def _blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)


def test_documented_problem_example_parses_and_plans() -> None:
    (example,) = _blocks("json")
    problem = Problem.from_json(json.loads(example))
    result = plan(problem, PlanOptions(method="auto"))
    assert [p.id for p in result.placed] == ["m1"]
    assert result.optimal is True


def test_documented_python_example_runs() -> None:
    (example,) = _blocks("python")
    namespace: dict[str, object] = {}
    exec(example, namespace)
    assert len(namespace["slots"]) == 18  # type: ignore[arg-type]
