"""The problem format: the documented example parses, and each class of bad input names its field."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from planning.placement import InvalidProblem, Problem

EXAMPLE: dict[str, Any] = {
    "tray": {"size_mm": [475, 520], "origin_mm": [250, -260]},
    "tolerance_mm": 10,
    "allow_rotation": False,
    "mug_types": {
        "big": {"diameter_mm": 91, "width_mm": 120, "height_mm": 106, "mass_kg": 0.2},
        "small": {"diameter_mm": 74, "width_mm": 100, "height_mm": 80, "mass_kg": 0.1},
    },
    "mugs": [{"id": "m1", "type": "big", "x_mm": 420, "y_mm": 310}],
    "placed": [{"id": "p1", "type": "small", "x_mm": 0, "y_mm": 0, "rotated": False}],
}


def test_documented_example_parses_and_round_trips() -> None:
    p = Problem.from_json(EXAMPLE)
    assert p.tray_size_mm == (475, 520)
    assert p.tray_origin_mm == (250.0, -260.0)
    assert p.footprint("big") == (130, 101)
    assert p.footprint("big", rotated=True) == (101, 130)
    assert [m.id for m in p.mugs] == ["m1"]
    assert p.placed[0].type == "small"
    assert Problem.from_json(p.to_json()) == p


def _with(path: str, value: object) -> dict[str, Any]:
    doc = copy.deepcopy(EXAMPLE)
    *parents, last = path.split(".")
    node: Any = doc
    for key in parents:
        node = node[int(key)] if key.isdigit() else node[key]
    if value is _DELETE:
        del node[int(last) if last.isdigit() else last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return doc


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("mugs.0.type", "huge", "mugs[0].type: unknown mug type 'huge' (known: big, small)"),
        ("tray.size_mm", [475, 0], "tray.size_mm[1]: must be positive, got 0"),
        ("tray.size_mm", [475, "wide"], "tray.size_mm[1]: expected a number, got a string ('wide')"),
        ("tray.size_mm", [475], "tray.size_mm: expected a list of two numbers [x, y], got a list"),
        ("tray", _DELETE, "tray: expected an object, got nothing"),
        ("mug_types.big.diameter_mm", -3, "mug_types.big.diameter_mm: must be positive, got -3"),
        (
            "mug_types.big.mass_kg",
            "heavy",
            "mug_types.big.mass_kg: expected a number, got a string ('heavy')",
        ),
        (
            "mug_types.big.width_mm",
            80,
            "mug_types.big.width_mm: 80 is less than the brim diameter 91 (width includes the handle)",
        ),
        (
            "mug_types.big.width_mm",
            600,
            "mugs[0].type: a 'big' mug (610 x 101 mm with tolerance) is larger than the tray (475 x 520 mm)",
        ),
        ("mugs.0.x_mm", None, "mugs[0].x_mm: expected a number, got nothing"),
        ("mugs.0.id", "p1", "placed[0].id: duplicate mug id 'p1'"),
        ("mugs", {}, "mugs: expected a list of mugs, got an object"),
        ("placed.0.x_mm", 470, "placed[0]: footprint [470, 580] x [0, 84] mm leaves the tray (475 x 520 mm)"),
        ("placed.0.x_mm", 2.5, "placed[0].x_mm: expected whole millimetres, got 2.5"),
        ("placed.0.rotated", "no", "placed[0].rotated: expected true or false, got a string ('no')"),
        ("tolerance_mm", -1, "tolerance_mm: must be at least 0, got -1"),
        ("allow_rotation", 1, "allow_rotation: expected true or false, got a number (1)"),
        (
            "colour",
            "red",
            "colour: unknown field (known: allow_rotation, arm, footprint, mug_types, mugs, placed,"
            " tolerance_mm, tray)",
        ),
    ],
)
def test_bad_input_names_the_field(path: str, value: object, message: str) -> None:
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json(_with(path, value))
    assert str(e.value) == message


def test_overlapping_mugs_on_the_tray_are_refused() -> None:
    doc = copy.deepcopy(EXAMPLE)
    doc["placed"].append({"id": "p2", "type": "big", "x_mm": 50, "y_mm": 40})
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json(doc)
    assert str(e.value) == "placed[1]: overlaps placed[0] (footprints with tolerance)"


def test_non_object_problem_is_refused() -> None:
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json([1, 2])  # type: ignore[arg-type]
    assert str(e.value) == "problem: expected a JSON object, got a list"
