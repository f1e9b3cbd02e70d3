"""The planner's layouts do not drift when its code is made faster: each dataset's plan (best heuristic for
the rectangle start, so nothing depends on a solver's clock) hashes to what main's planner gave before the
mug packer's speed-up (the spots, their order, what stays on the counter, the notes, the costs to 4 digits).

A change that means to change a layout updates these hashes and says so; one that only means to be faster
must leave them alone."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace

import pytest

from planning.placement import PlanOptions, dataset_problem, plan

GOLDEN = {
    ("mug", 1): "8d885df28478a66f",
    ("mug", 2): "f6e167e229c9a224",
    ("mug", 3): "1a47c249b40e77c9",
    ("mug", 4): "9b2bbae854d4b649",
    ("mug", 5): "81c0c9661ccfc8c6",
    ("mug", 6): "d35d8d4bd66215a2",
    ("rect", 1): "12d7f619c469661e",
    ("rect", 2): "5948f86f6c46c708",
    ("rect", 3): "37230c5505050f3c",
    ("rect", 4): "795fc7154fcc25b0",
    ("rect", 5): "52a08e2cde8243e3",
    ("rect", 6): "d156e83046816204",
}


def digest(result: dict[str, object]) -> str:
    placed = result["placed"]
    assert isinstance(placed, list)
    cost, energy = result["cost"], result["E"]
    assert isinstance(cost, float)
    assert isinstance(energy, float)
    key = {
        "placed": [[p["id"], p["x_mm"], p["y_mm"], p["order"], p["rotated"]] for p in placed],
        "unplaced": result["unplaced"],
        "n": result["n"],
        "notes": result["notes"],
        "cost": round(cost, 4),
        "E": round(energy, 3),
        "upper_bound": result["upper_bound"],
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


@pytest.mark.parametrize(
    ("footprint", "dataset"),
    [
        pytest.param(f, n, marks=[pytest.mark.slow] if (f, n) in {("mug", 4), ("mug", 5), ("mug", 6)} else [])
        for f, n in GOLDEN
    ],
)
def test_the_plan_is_the_one_main_made(footprint: str, dataset: int) -> None:
    problem = replace(dataset_problem(dataset), footprint_kind=footprint)
    result = plan(problem, PlanOptions(method="bh")).to_json()
    assert digest(result) == GOLDEN[(footprint, dataset)]
