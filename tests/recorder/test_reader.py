"""The reader's JSON: msgspec's decoder where it can, ``json``'s for what only it reads (an older writer's
``NaN``), the same values either way; a compact read only checks each message is a JSON object."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from recorder.reader import decoded_as, is_json_object, json_object
from wire.messages import BadMessage, Holding

_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**63 - 1) | st.floats(allow_nan=False) | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


@given(st.dictionaries(st.text(max_size=8), _values, max_size=6))
def test_a_json_object_decodes_as_json_decodes_it(document: dict[str, object]) -> None:
    raw = json.dumps(document).encode()
    assert is_json_object(raw)
    assert json_object(raw) == json.loads(raw)


def test_what_only_json_reads_is_still_read() -> None:
    raw = b'{"force_n": NaN, "t": Infinity}'
    assert is_json_object(raw)
    value = json_object(raw)
    assert math.isnan(value["force_n"])  # type: ignore[arg-type]
    assert value["t"] == math.inf


@pytest.mark.parametrize("raw", [b"[1, 2]", b"3", b'"text"', b"null"])
def test_json_that_is_not_an_object_is_told(raw: bytes) -> None:
    assert not is_json_object(raw)


@pytest.mark.parametrize("raw", [b"{not json", b'{"a": 1} trailing', b""])
def test_bytes_that_are_not_json_raise_value_error(raw: bytes) -> None:
    with pytest.raises(ValueError, match=r"Expecting|Extra data"):  # (``json``'s word on them)
        is_json_object(raw)


def test_decoding_straight_into_a_message_checks_it_as_a_conversion_does() -> None:
    assert decoded_as(b'{"holding": true, "t_read": 1.5}', Holding) == Holding(holding=True, t_read=1.5)
    with pytest.raises(BadMessage, match=r"input/holding: holding: expected `bool`, got `int`"):
        decoded_as(b'{"holding": 1, "t_read": 1.5}', Holding, name="input/holding")
    with pytest.raises(BadMessage, match=r"holding: expected `bool`, got `float`"):
        decoded_as(b'{"holding": NaN, "t_read": 1.5}', Holding)
