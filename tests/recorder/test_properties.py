"""Property tests: any JSON object survives a recording."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from recorder import Recorder, read_messages

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**53), max_value=2**53)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=20),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=12,
)
json_objects = st.dictionaries(st.text(max_size=8), json_values, max_size=5)

_counter = itertools.count()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(payloads=st.lists(st.tuples(st.sampled_from(["a/x", "a/y", "b/**"]), json_objects), max_size=20))
@pytest.mark.slow
def test_any_json_objects_read_back_exactly(
    tmp_path: Path, payloads: list[tuple[str, dict[str, object]]]
) -> None:
    path = tmp_path / f"p{next(_counter)}.mcap"
    with Recorder(path, chunk_size=1024) as rec:
        for i, (topic, payload) in enumerate(payloads):
            rec.write(topic, payload, log_time_ns=i)
    got = read_messages(path)
    assert not got.truncated
    assert [(m.topic, m.log_time_ns, m.payload) for m in got] == [
        (topic, i, payload) for i, (topic, payload) in enumerate(payloads)
    ]
