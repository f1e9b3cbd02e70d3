"""The one TOML writer: what it writes reads back as the same data."""

from __future__ import annotations

import math
import tomllib
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from validation import toml

_scalars = st.booleans() | st.integers(-(2**63), 2**63 - 1) | st.floats(allow_nan=False) | st.text(max_size=8)
_keys = st.text(min_size=1, max_size=6)


def _tables(depth: int) -> st.SearchStrategy[dict[str, Any]]:
    values: st.SearchStrategy[Any] = _scalars | st.lists(_scalars, max_size=3)
    if depth > 0:
        values = values | _tables(depth - 1) | st.lists(_tables(depth - 1), min_size=1, max_size=2)
    return st.dictionaries(_keys, values, max_size=4)


@settings(max_examples=300, deadline=None)
@given(data=_tables(2))
def test_what_is_written_reads_back_the_same(data: dict[str, Any]) -> None:
    assert tomllib.loads(toml.dumps(data)) == data


def test_control_characters_and_quotes_never_break_a_line() -> None:
    text = toml.dumps({"note": 'a "b"\n\tc\x00\x7f\\', "weird key.x": 1})
    assert text.count("\n") == 2
    assert tomllib.loads(text) == {"note": 'a "b"\n\tc\x00\x7f\\', "weird key.x": 1}


def test_non_finite_floats_and_lists_of_tables() -> None:
    data = {"fault": [{"kind": "fsr_drop", "at_s": math.inf}, {"kind": "sigterm", "at_s": 1.5}], "t": {}}
    back = tomllib.loads(toml.dumps(data))
    assert back == data
    assert toml.dumps({"x": math.nan}) == "x = nan\n"


def test_anything_else_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="cannot write object as TOML"):
        toml.dumps({"x": object()})
