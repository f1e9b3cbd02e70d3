"""A replay's loading holds only what it reads, compactly (issue 22, streaming replay): the topics a replay
never reads are counted, not decoded; the others keep their JSON bytes, decoded when used, so a loaded
session takes about its recording's size, not several times it; and what it serves is exactly what a full
decode of the file gives, for a finished recording and for one cut by a crash (which has no index)."""

from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from recorder import HEADER_TOPIC, read_messages
from recorder.errors import RecordingError
from replay.engine import replay
from replay.errors import ReplayError
from replay.session import RecordedSession, replayed_topic, trace_of, traced_topic
from wire.messages import TOPICS, convert, topic_suffix

RIG_RECORDING = Path(__file__).parents[1] / "data" / "rig-2mugs-job.mcap"


def test_a_loaded_session_keeps_only_the_topics_a_replay_reads_and_those_as_json_bytes() -> None:
    session = RecordedSession.load(RIG_RECORDING)
    everything = read_messages(RIG_RECORDING)
    kept = {m.topic for m in session.read.messages}
    assert kept == {m.topic for m in everything.messages if replayed_topic(m.topic)}
    assert kept < set(everything.topic_counts)
    # Counted, never decoded: the telemetry, the log and Foxglove's views.
    for topic in ("/tf", "dishbot/dishbot/joints", "dishbot/dishbot/log"):
        assert everything.topic_counts.get(topic, 0) > 0, topic
        assert session.read.topic_counts[topic] == everything.topic_counts[topic]
        assert topic not in kept
    assert all(m.raw is not None for m in session.read.messages)
    assert session.read.message_count == everything.message_count


@pytest.mark.parametrize(
    "topic", ["/tf", "dishbot/dishbot/joints", "dishbot/dishbot/log", "/scene/plan", "/events"]
)
def test_the_topics_a_replay_does_not_read(topic: str) -> None:
    assert not replayed_topic(topic)


@pytest.mark.parametrize(
    "topic",
    [HEADER_TOPIC, "dishbot/r/events", "dishbot/r/state", "dishbot/r/plan", "dishbot/r/gripper",
     "dishbot/r/detections", "dishbot/r/input/joints", "dishbot/r/input/motion", "dishbot/r/output/follow"],
)  # fmt: skip
def test_the_topics_a_replay_reads(topic: str) -> None:
    assert replayed_topic(topic)


def test_a_replays_tee_keeps_only_what_makes_a_trace() -> None:
    assert traced_topic("dishbot/r/events")
    assert traced_topic("dishbot/r/output/follow")
    assert traced_topic("dishbot/r/input/grasp")
    assert traced_topic("dishbot/r/state")
    assert not traced_topic("dishbot/r/input/joints")
    assert not traced_topic("dishbot/r/gripper")


def _as_loaded_by_a_full_decode(path: Path) -> dict[str, list[tuple[int, dict[str, object], object]]]:
    """The driver-boundary streams as a full decode of ``path`` gives them (every topic, as dicts)."""
    streams: dict[str, list[tuple[int, dict[str, object], object]]] = {}
    for m in read_messages(path).messages[1:]:
        suffix = topic_suffix(m.topic)
        if suffix.startswith(("input/", "output/")) or suffix == "plan":
            declared = None if suffix in ("input/device_event", "plan") else TOPICS.get(suffix)
            message = None if declared is None else convert(m.payload, declared, name=suffix)
            streams.setdefault(suffix, []).append((m.log_time_ns, m.payload, message))
    return streams


def _assert_as_a_full_decode(path: Path) -> RecordedSession:
    session = RecordedSession.load(path)
    expected = _as_loaded_by_a_full_decode(path)
    assert set(session.streams) == set(expected)
    for suffix, records in session.streams.items():
        got = [(r.t_ns, dict(r.payload), r.message) for r in records]
        assert got == expected[suffix], suffix
        assert all(r.kind == suffix for r in records)
    assert session.trace == trace_of(read_messages(path), start_ns=session.start_ns)
    return session


def test_what_a_loaded_session_serves_is_what_a_full_decode_of_the_file_gives() -> None:
    session = _assert_as_a_full_decode(RIG_RECORDING)
    assert "input/joints" in session.streams


@pytest.mark.parametrize("fraction", [0.35, 0.7])
def test_a_recording_cut_by_a_crash_loads_compactly_up_to_the_cut(fraction: float, tmp_path: Path) -> None:
    """A cut file has no summary nor chunk index: it is read record by record, up to the cut."""
    data = RIG_RECORDING.read_bytes()
    cut = tmp_path / "cut-job.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    session = _assert_as_a_full_decode(cut)
    assert session.cut is not None
    whole = RecordedSession.load(RIG_RECORDING)
    assert 0 < len(session.trace.states) < len(whole.trace.states)
    assert session.trace.states == whole.trace.states[: len(session.trace.states)]


def _with_broken(source: Path, target: Path, broken: str) -> Path:
    """``source`` written again (every schema, channel and message as it is) with the payload of every
    ``broken`` message replaced by bytes that are not JSON."""
    with source.open("rb") as f, target.open("wb") as out:
        writer = Writer(out)
        writer.start(profile="", library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0)
                )
            data = b"{not json" if channel.topic == broken else message.data
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        writer.finish()  # type: ignore[no-untyped-call]
    return target


def test_a_topic_a_replay_does_not_read_is_never_decoded(tmp_path: Path) -> None:
    """The telemetry's joints broken: a full read stops at them; a replay's load never decodes them."""
    broken = _with_broken(RIG_RECORDING, tmp_path / "broken-joints-job.mcap", "dishbot/dishbot/joints")
    with pytest.raises(RecordingError, match=r"dishbot/dishbot/joints at byte .* is not JSON"):
        read_messages(broken)
    session = _assert_as_a_full_decode(RIG_RECORDING)
    again = RecordedSession.load(broken)
    assert again.trace == session.trace
    assert again.read.topic_counts == session.read.topic_counts


def test_a_message_a_replay_reads_that_is_not_json_is_still_refused(tmp_path: Path) -> None:
    """Read compactly, each kept message is still decoded once while loading: a broken one is named then,
    in one line."""
    broken = _with_broken(RIG_RECORDING, tmp_path / "broken-force-job.mcap", "dishbot/dishbot/input/force")
    with pytest.raises(ReplayError, match=r"dishbot/dishbot/input/force at byte .* is not JSON"):
        RecordedSession.load(broken)


def test_a_loaded_session_takes_about_the_size_of_the_json_it_keeps() -> None:
    """Counted by the allocator (``tracemalloc``), not timed: the session holds the kept messages' JSON
    bytes plus a bounded overhead per message (its records), not a decoded dict per message (several
    times the bytes: what a full decode holds)."""
    gc.collect()
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        session = RecordedSession.load(RIG_RECORDING)
        gc.collect()
        held, _ = tracemalloc.get_traced_memory()
        held -= before
        raw = sum(len(m.raw or b"") for m in session.read.messages)
        n = len(session.read.messages)
        bound = raw + 200 * n + 4_000_000  # + the header, config and schemas
        assert held <= bound, f"{held} bytes held for {n} messages of {raw} bytes"

        before_full, _ = tracemalloc.get_traced_memory()
        full = read_messages(RIG_RECORDING, keep=replayed_topic)
        full_held = tracemalloc.get_traced_memory()[0] - before_full
        # The same messages as dicts: what loading used to hold for them (and the streams' typed copies).
        assert len(full.messages) == n
        assert full_held > 2 * (held - 4_000_000)
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_a_cut_robot_recording_replays_to_a_match_up_to_its_cut(tmp_path: Path) -> None:
    data = RIG_RECORDING.read_bytes()
    cut = tmp_path / "cut-job.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    session = RecordedSession.load(cut)
    assert session.cut is not None
    report = replay(session)
    assert report.cut == session.cut
    assert report.match, report.first_divergence
    assert report.replayed.states[: len(session.trace.states)] == session.trace.states


def test_the_timed_inputs_taken_at_load_are_those_of_a_decode_of_every_record() -> None:
    """``load`` decodes each input once and takes what the replay serves it by from that decode; the same
    facts come out of decoding the streams' records again (``with_streams``)."""
    session = RecordedSession.load(RIG_RECORDING)
    again = session.with_streams({})
    assert set(session.timed) == {"input/joints", "input/force", "input/holding"}
    for name, timed in session.timed.items():
        assert timed == again.timed[name], name
        assert list(timed.read_times) == sorted(timed.read_times)
        assert len(timed.records) == len(timed.ok) == len(timed.readers)
    joints = session.timed["input/joints"]
    assert len(joints.records) == len(session.streams["input/joints"]) + len(
        session.streams.get("input/joints_failed", ())
    )
    holding = session.timed["input/holding"]
    assert len(holding.holding) == len(holding.records) > 0
    assert True in holding.holding
