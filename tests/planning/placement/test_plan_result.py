"""``PlanResult.from_json``: a recorded plan read back through the one validator, old recordings included."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planning.placement import PlanOptions, PlanResult, dataset_problem, plan
from tests.planning.placement.edit import DELETE, edited
from validation import Invalid


def _planned() -> dict[str, Any]:
    return plan(dataset_problem(1), PlanOptions(method="bh", seed=1, time_limit_s=5.0)).to_json()


DOC = _planned()


def test_a_written_plan_reads_back_as_itself() -> None:
    result = PlanResult.from_json(DOC)
    assert result.to_json() == DOC
    assert result.placed
    assert all(p.brim_mm is not None for p in result.placed)
    assert isinstance(result.A_mm2, float)


def test_the_published_message_reads_back_with_its_own_keys_passed_over() -> None:
    """The ``plan`` topic adds ``slots`` and ``out_of_reach`` and moves the time estimate to ``t_plan_s``
    (its ``t`` is the time of publication)."""
    message = {**DOC, "t_plan_s": DOC["t"], "t": 1.7e9, "slots": [{"id": "x"}], "out_of_reach": []}
    assert PlanResult.from_json(message).to_json() == DOC


def test_a_plan_recorded_before_later_fields_existed_still_reads() -> None:
    old = {k: v for k, v in DOC.items() if k not in ("evaluations", "notes", "status", "sort", "optimal")}
    old["placed"] = [
        {k: v for k, v in p.items() if k not in ("brim_mm", "handle_yaw_rad")} for p in DOC["placed"]
    ]
    result = PlanResult.from_json(old)
    assert (result.evaluations, result.notes, result.status, result.sort) == (0, (), "feasible", None)
    assert all(p.brim_mm is None and p.handle_yaw_rad is None for p in result.placed)


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("method", DELETE, "plan.method: missing"),
        ("t", DELETE, "plan.t: missing"),
        ("n", "six", "plan.n: expected an integer, got 'six'"),
        ("n", 6.0, "plan.n: expected an integer, got 6"),
        ("seed", True, "plan.seed: expected an integer, got true"),
        ("A", "big", "plan.A: expected a number, got 'big'"),
        ("optimal", "yes", "plan.optimal: expected true or false, got 'yes'"),
        ("unplaced", "m1", "plan.unplaced: expected a list, got 'm1'"),
        ("unplaced", [3], "plan.unplaced[0]: expected a string, got 3"),
        ("placed.0", 3, "plan.placed[0]: expected a table, got 3"),
        ("placed.0.x_mm", None, "plan.placed[0].x_mm: expected an integer, got None"),
        ("placed.0.order", DELETE, "plan.placed[0].order: missing"),
        ("placed.0.brim_mm", [1.0], "plan.placed[0].brim_mm: expected 2 values, got 1"),
        ("placed.0.rotated", 0, "plan.placed[0].rotated: expected true or false, got 0"),
    ],
)
def test_a_bad_recorded_plan_names_the_field(path: str, value: object, message: str) -> None:
    with pytest.raises(ValueError, match=r".") as e:
        PlanResult.from_json(edited(DOC, path, value))
    assert isinstance(e.value, Invalid)
    assert str(e.value) == message


def test_a_plan_that_is_not_an_object_is_refused() -> None:
    with pytest.raises(Invalid) as e:
        PlanResult.from_json(["plan"])
    assert str(e.value) == "plan: expected a table, got a list"


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=4),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.sampled_from(sorted(DOC)), inner, max_size=4)
    ),
    max_leaves=10,
)


@settings(max_examples=200, deadline=None)
@given(change=st.dictionaries(st.sampled_from(sorted(DOC)), _json, max_size=3))
def test_any_change_reads_or_is_refused_in_one_line_naming_the_plan(change: dict[str, Any]) -> None:
    try:
        PlanResult.from_json({**DOC, **change})
        text = ""
    except Invalid as e:
        text = str(e)
    assert "\n" not in text
    assert not text or text.startswith("plan.")
