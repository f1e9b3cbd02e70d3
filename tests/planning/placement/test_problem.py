"""The problem format: the documented example parses, and each class of bad input names its field."""

from __future__ import annotations

import copy
import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planning.placement import InvalidProblem, Problem
from tests.planning.placement.edit import DELETE, edited

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


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("mugs.0.type", "huge", "mugs[0].type: unknown mug type 'huge' (known: big, small)"),
        ("tray.size_mm", [475, 0], "tray.size_mm[1]: 0 is out of range; allowed (0, 10000] mm"),
        (
            "tray.size_mm",
            [475, "wide"],
            "tray.size_mm[1]: expected a number in (0, 10000] mm, got 'wide'",
        ),
        ("tray.size_mm", [475], "tray.size_mm: expected 2 values, got 1"),
        ("tray", DELETE, "tray: missing"),
        (
            "mug_types.big.diameter_mm",
            -3,
            "mug_types.big.diameter_mm: -3 is out of range; allowed (0, 1000] mm",
        ),
        (
            "mug_types.big.mass_kg",
            "heavy",
            "mug_types.big.mass_kg: expected a number in (0, 100] kg, got 'heavy'",
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
        ("mugs.0.x_mm", None, "mugs[0].x_mm: expected a finite number, got None"),
        ("mugs.0.id", "p1", "placed[0].id: duplicate mug id 'p1'"),
        ("mugs", {}, "mugs: expected a list, got a table"),
        ("placed.0.x_mm", 470, "placed[0]: footprint [470, 580] x [0, 84] mm leaves the tray (475 x 520 mm)"),
        ("placed.0.x_mm", 2.5, "placed[0].x_mm: expected whole millimetres, got 2.5"),
        ("placed.0.x_mm", -1, "placed[0].x_mm: -1 is out of range; allowed [0, 10000] mm"),
        ("placed.0.id", DELETE, "placed[0].id: missing"),
        ("placed.0.id", "", "placed[0].id: expected a non-empty string, got ''"),
        ("tray.size_mm", [475, 520.5], "tray.size_mm[1]: expected whole millimetres, got 520.5"),
        ("tray.size_mm", [475, 20_000], "tray.size_mm[1]: 20000 is out of range; allowed (0, 10000] mm"),
        ("tray.origin_mm", [0, math.inf], "tray.origin_mm[1]: expected a finite number, got inf"),
        ("mugs.0.x_mm", math.nan, "mugs[0].x_mm: expected a finite number, got nan"),
        ("mugs.0.type", DELETE, "mugs[0].type: missing"),
        ("mugs.0.type", 3, "mugs[0].type: expected a string, got 3"),
        ("mugs", DELETE, "mugs: missing"),
        ("mug_types", {}, "mug_types: must name at least one mug type"),
        ("mug_types.big.height_mm", 80.5, "mug_types.big.height_mm: expected whole millimetres, got 80.5"),
        ("mug_types.big.mass_kg", DELETE, "mug_types.big.mass_kg: missing"),
        ("mug_types.big", [91, 120], "mug_types.big: expected a table, got a list"),
        ("tolerance_mm", 2.5, "tolerance_mm: expected whole millimetres, got 2.5"),
        ("footprint", "round", "footprint: 'round' is not one of rect, mug"),
        ("arm", {"speed_m_s": 0}, "arm.speed_m_s: 0 is out of range; allowed (0, 100] m/s"),
        ("arm", {"base_mm": [0, "here"]}, "arm.base_mm[1]: expected a finite number, got 'here'"),
        ("arm", 3, "arm: expected a table, got 3"),
        ("placed.0.rotated", "no", "placed[0].rotated: expected true or false, got 'no'"),
        ("tolerance_mm", -1, "tolerance_mm: -1 is out of range; allowed [0, 1000] mm"),
        ("allow_rotation", 1, "allow_rotation: expected true or false, got 1"),
        (
            "colour",
            "red",
            "colour: unknown key in the problem (known keys: allow_rotation, arm, footprint, mug_types,"
            " mugs, placed, strays, tolerance_mm, tray)",
        ),
    ],
)
def test_bad_input_names_the_field(path: str, value: object, message: str) -> None:
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json(edited(EXAMPLE, path, value))
    assert str(e.value) == message


def test_overlapping_mugs_on_the_tray_are_refused() -> None:
    doc = copy.deepcopy(EXAMPLE)
    doc["placed"].append({"id": "p2", "type": "big", "x_mm": 50, "y_mm": 40})
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json(doc)
    assert str(e.value) == "placed[1]: overlaps placed[0] (footprints with tolerance)"


def test_what_the_old_parser_accepted_is_still_accepted() -> None:
    """Whole millimetres written as 475.0, null for an optional table or pair, and keys inside the tables
    that the format does not name (a result's ``placed`` entry, ``order`` and ``brim_mm`` with it)."""
    doc = copy.deepcopy(EXAMPLE)
    doc["tray"] = {"size_mm": [475.0, 520.0], "origin_mm": None}
    doc["arm"] = None
    doc["tolerance_mm"] = 10.0
    doc["placed"][0] |= {"x_mm": 0.0, "order": 1, "brim_mm": [42.0, 42.0], "handle_yaw_rad": None}
    doc["mugs"][0]["colour"] = "blue"
    p = Problem.from_json(doc)
    assert (p.tray_size_mm, p.tray_origin_mm, p.arm_base_mm, p.tolerance_mm) == (
        (475, 520),
        (0, 0),
        (0, 0),
        10,
    )
    assert all(isinstance(v, int) for v in (*p.tray_size_mm, p.placed[0].x_mm, p.tolerance_mm))
    assert p.placed[0].handle_yaw_rad is None
    assert p == Problem.from_json({**EXAMPLE, "tray": {"size_mm": [475, 520]}})


def test_a_problem_without_optional_fields_takes_the_defaults() -> None:
    p = Problem.from_json({"tray": {"size_mm": [332, 374]}, "mugs": []})
    assert (p.tolerance_mm, p.allow_rotation, p.footprint_kind, p.arm_speed_m_s) == (10, False, "rect", 0.1)
    assert sorted(p.mug_types) == ["big", "small"]
    assert p.placed == ()


def test_non_object_problem_is_refused() -> None:
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json([1, 2])
    assert str(e.value) == "the problem: expected a table, got a list"


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=12), inner, max_size=4),
    max_leaves=10,
)
_paths = st.sampled_from(
    [
        "tray",
        "tray.size_mm",
        "tray.size_mm.0",
        "tray.origin_mm",
        "tolerance_mm",
        "footprint",
        "mug_types",
        "mug_types.big",
        "mug_types.big.width_mm",
        "mugs",
        "mugs.0",
        "mugs.0.x_mm",
        "mugs.0.handle_yaw_rad",
        "placed.0",
        "placed.0.y_mm",
        "arm",
    ]
)


@settings(max_examples=300, deadline=None)
@given(path=_paths, value=_json)
def test_any_json_in_any_place_is_a_problem_or_one_line_naming_a_field(path: str, value: object) -> None:
    try:
        Problem.from_json(edited(EXAMPLE, path, value))
        text = ""
    except InvalidProblem as e:
        text = str(e)
    assert "\n" not in text
    assert len(text) < 300


@pytest.mark.parametrize("key", ["\n", "a b", "x\ny"])
def test_a_mug_type_named_with_a_line_break_is_named_on_one_line(key: str) -> None:
    """Found by the property above: the type's name went into the error as it was, line break included."""
    with pytest.raises(InvalidProblem) as e:
        Problem.from_json(edited(EXAMPLE, "mug_types", {key: None}))
    assert "\n" not in str(e.value)
    assert str(e.value).startswith(f"mug_types[{key!r}]: ")
