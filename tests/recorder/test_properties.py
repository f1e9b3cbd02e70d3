"""Property tests: any JSON object survives a recording, and any fault plan applies deterministically."""

from __future__ import annotations

import itertools
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from recorder import Recorder, read_messages
from replay.errors import ReplayError
from replay.streams import FaultPlan, Timeline

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


window = st.tuples(st.floats(0.0, 4.0), st.floats(0.05, 2.0)).map(lambda w: (w[0], w[0] + w[1]))
fault_steps = st.lists(
    st.one_of(
        st.tuples(st.just("drop"), st.sampled_from(["force", "joints"]), window),
        st.tuples(st.just("delay"), st.sampled_from(["force", "joints"]), window, st.floats(0.01, 1.0)),
        st.tuples(st.just("noise"), st.just("force"), window, st.integers(0, 2**31)),
        st.tuples(st.just("spike"), st.just("force"), st.floats(0.0, 4.0)),
        st.tuples(st.just("cut"), st.sampled_from(["force", "joints", None]), st.floats(0.5, 4.0)),
    ),
    max_size=5,
)


def build(steps: list[tuple[Any, ...]]) -> FaultPlan:
    plan = FaultPlan()
    for step in steps:
        match step:
            case ("drop", stream, (start, end)):
                plan = plan.drop(stream, start, end)
            case ("delay", stream, (start, end), by):
                plan = plan.delay(stream, start, end, by_s=by)
            case ("noise", stream, (start, end), seed):
                plan = plan.noise(stream, start, end, "force_n", sigma=0.5, seed=seed)
            case ("spike", stream, at):
                plan = plan.spike(stream, at, "force_n", 99.0)
            case ("cut", stream, at):
                plan = plan.cut(at, stream)
    return plan


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(steps=fault_steps)
def test_fault_plans_are_deterministic_and_keep_streams_ordered(
    make_recording: Callable[..., Path], tmp_path: Path, steps: list[tuple[object, ...]]
) -> None:
    path = tmp_path / "session.mcap"
    timeline = Timeline.from_recording(path if path.exists() else make_recording(seconds=4.0))
    plan = build(steps)
    try:
        first = plan.apply(timeline)
    except ReplayError as e:  # a fault that missed its stream is refused, the same way every time
        event("refused")
        with pytest.raises(ReplayError, match=f"^{re.escape(str(e))}$"):
            plan.apply(timeline)
        return
    assert plan.apply(timeline) == first
    assert len(first.faults) == len(steps)
    for items in first.streams.values():
        assert [x.t_s for x in items] == sorted(x.t_s for x in items)
        assert all(x.t_s <= first.end_s for x in items)
    assert len(timeline.stream("force")) == 200
