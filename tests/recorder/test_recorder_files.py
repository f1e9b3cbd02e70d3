"""The Recorder writes MCAP files that read back exactly, and read_messages recovers files cut anywhere."""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from recorder import HEADER_TOPIC, Recorder, read_messages, writer
from recorder.errors import RecordingError
from recorder.writer import header_payload
from tests.fakes.disk import SmallDisk

RecordingFactory = Callable[..., Path]


def test_finished_file_reads_back_every_message_in_order(
    make_recording: RecordingFactory, t0_ns: int
) -> None:
    path = make_recording(seconds=2.0)
    rec = read_messages(path)
    assert not rec.truncated
    assert rec.cut_at_byte is None
    assert rec.cut_after_ns is None
    assert rec.topic_counts == {
        HEADER_TOPIC: 1,
        "dishbot/r1/input/joints": 100,
        "dishbot/r1/input/force": 100,
        "dishbot/r1/input/observation": 4,
    }
    assert rec.header == {
        "config": {"robot_id": "r1", "backend": "sim"},
        "scene": {"dataset": 1, "mugs": [{"id": "m0", "type": "big", "x_m": 0.1, "y_m": 0.3}]},
    }
    force = [m for m in rec if m.topic == "dishbot/r1/input/force"]
    assert [m.payload["seq"] for m in force] == list(range(100))
    assert [m.log_time_ns for m in force] == [t0_ns + i * 20_000_000 + 1_000_000 for i in range(100)]
    assert rec.start_ns == t0_ns
    assert rec.end_ns == t0_ns + 99 * 20_000_000 + 1_000_000


def test_finished_file_opens_with_the_standard_mcap_reader(make_recording: RecordingFactory) -> None:
    path = make_recording(seconds=1.0)
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == {
            HEADER_TOPIC,
            "dishbot/r1/input/joints",
            "dishbot/r1/input/force",
            "dishbot/r1/input/observation",
        }
        assert all(c.message_encoding == "json" for c in topics.values())
        schema = summary.schemas[topics["dishbot/r1/input/force"].schema_id]
        assert schema.encoding == "jsonschema"
        assert schema.name == "dishbot.input_force"
        doc = json.loads(schema.data)
        assert {k: v["type"] for k, v in doc["properties"].items()} == {
            "t": "number",
            "t_device": "number",
            "t_read": "number",
            "force_n": "number",
            "raw": "integer",
            "seq": "integer",
        }
        assert doc["required"] == ["force_n"]
        assert summary.statistics is not None
        assert summary.statistics.message_count == 1 + 50 + 50 + 2


def test_the_summary_points_at_every_chunk_where_it_lies_in_the_file(tmp_path: Path) -> None:
    # The file counts the bytes it wrote rather than asking the OS where it is: the offsets it gives the
    # MCAP writer (chunk starts, message indexes, the summary) must be those of the file on disk.
    path = tmp_path / "chunks.mcap"
    with Recorder(path, chunk_size=1024, flush_interval_s=0.1, drain_interval_s=0.01) as rec:
        for i in range(3000):
            rec.write("dishbot/r1/joints", {"i": i, "pad": "x" * (i % 97)}, log_time_ns=1_000 + i)
    data = path.read_bytes()
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert len(summary.chunk_indexes) > 50
        for chunk in summary.chunk_indexes:
            assert data[chunk.chunk_start_offset] == 0x06  # a Chunk record's opcode
        got = [json.loads(m.data)["i"] for _, _, m in reader.iter_messages(log_time_order=True)]
    assert got == list(range(3000))


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_compressed_recording_round_trips(make_recording: RecordingFactory, compression: str) -> None:
    path = make_recording(seconds=1.0, compression=compression)
    rec = read_messages(path)
    assert not rec.truncated
    assert rec.message_count == 103


def test_file_copied_partway_recovers_messages_up_to_the_cut(
    make_recording: RecordingFactory, tmp_path: Path
) -> None:
    path = make_recording(seconds=4.0)
    full = read_messages(path)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    rec = read_messages(cut)
    assert rec.truncated
    assert rec.cut_reason == "file ends mid-record"
    assert rec.cut_at_byte is not None
    assert rec.cut_at_byte <= len(data) // 2
    assert 0 < len(rec) < len(full)
    assert list(rec) == list(full)[: len(rec)]
    assert rec.cut_after_ns == max(m.log_time_ns for m in rec)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(min_value=0.0, max_value=1.0, exclude_max=True))
def test_any_cut_yields_a_prefix_of_the_finished_file(
    make_recording: RecordingFactory, tmp_path: Path, fraction: float
) -> None:
    path = tmp_path / "session.mcap"
    if not path.exists():
        make_recording(seconds=1.0, chunk_size=1024)
    data = path.read_bytes()
    full = list(read_messages(path))
    n = 8 + math.floor(fraction * (len(data) - 8))
    cut = tmp_path / "prefix.mcap"
    cut.write_bytes(data[:n])
    rec = read_messages(cut)
    assert rec.truncated
    assert list(rec) == full[: len(rec)]
    assert rec.cut_at_byte is not None
    assert rec.cut_at_byte <= n


def test_corrupt_chunk_stops_reading_there_and_says_so(
    make_recording: RecordingFactory, tmp_path: Path
) -> None:
    path = make_recording(seconds=4.0)
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    rec_full = read_messages(path)
    # A copy ending in the middle is cut at the start of the record spanning the middle: a chunk.
    probe = tmp_path / "probe.mcap"
    probe.write_bytes(bytes(data[:middle]))
    boundary = read_messages(probe).cut_at_byte
    assert boundary is not None
    assert data[boundary] == 0x06
    data[boundary + 60] ^= 0xFF  # inside the chunk's records, after its header fields
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    rec = read_messages(bad)
    assert rec.truncated
    assert rec.cut_at_byte == boundary
    assert rec.cut_reason.startswith("corrupt chunk record")
    assert list(rec) == list(rec_full)[: len(rec)]
    assert 0 < len(rec) < len(rec_full)


def test_messages_written_from_several_threads_all_arrive_in_each_threads_order(tmp_path: Path) -> None:
    path = tmp_path / "threads.mcap"
    with Recorder(path, chunk_size=2048) as rec:

        def produce(k: int) -> None:
            for i in range(300):
                rec.write(f"dishbot/r1/t{k}", {"i": i}, log_time_ns=1_000 + i)

        threads = [threading.Thread(target=produce, args=(k,)) for k in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert rec.stats().dropped == 0
    got = read_messages(path)
    for k in range(4):
        assert [m.payload["i"] for m in got if m.topic == f"dishbot/r1/t{k}"] == list(range(300))


def test_full_queue_drops_and_counts_every_lost_message(tmp_path: Path) -> None:
    path = tmp_path / "drops.mcap"
    accepted = 0
    with Recorder(path, queue_size=1) as rec:
        for i in range(5000):
            accepted += rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i)
    stats = rec.stats()
    assert stats.dropped > 0
    assert stats.written == accepted
    assert stats.written + stats.dropped == 5000
    assert read_messages(path).message_count == stats.written


def test_recorder_in_a_missing_directory_fails_with_one_line(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "x.mcap"
    with pytest.raises(RecordingError) as err:
        Recorder(path)
    assert str(err.value) == f"cannot create recording {path}: No such file or directory"


def test_recorder_refuses_to_overwrite_an_existing_file(tmp_path: Path) -> None:
    path = tmp_path / "exists.mcap"
    path.write_bytes(b"keep me")
    with pytest.raises(
        RecordingError, match=r"^recording .*exists\.mcap already exists; choose a new file name$"
    ):
        Recorder(path)
    assert path.read_bytes() == b"keep me"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"compression": "gzip"},
            "recording compression 'gzip' is not supported; use one of: none, zstd, lz4",
        ),
        ({"chunk_size": 100}, "recording chunk_size 100 is too small; use at least 1024 bytes"),
        ({"flush_interval_s": 0.0}, "recording flush_interval_s 0.0 is out of range (0, 10] s"),
        ({"queue_size": 0}, "recording queue_size 0 must be at least 1"),
        (
            {"drain_interval_s": 1.0},
            "recording drain_interval_s 1.0 is out of range (0, flush_interval_s]",
        ),
    ],
)
def test_recorder_rejects_bad_settings_before_creating_the_file(
    tmp_path: Path, kwargs: dict[str, object], message: str
) -> None:
    path = tmp_path / "x.mcap"
    with pytest.raises(RecordingError) as err:
        Recorder(path, **kwargs)  # type: ignore[arg-type]
    assert str(err.value) == message
    assert not path.exists()


@pytest.mark.parametrize(
    ("topic", "payload", "log_time_ns", "message"),
    [
        ("", {"a": 1}, 0, "recording topic must be a non-empty key expression"),
        ("dishbot/r1/x", [1, 2], 0, "recording payload for 'dishbot/r1/x' must be a JSON object, got list"),
        (
            "dishbot/r1/x",
            {"a": 1},
            -1,
            "recording log_time_ns for 'dishbot/r1/x' must be an integer in [0, 2**64)",
        ),
        (
            "dishbot/r1/x",
            {"a": 1},
            1.5,
            "recording log_time_ns for 'dishbot/r1/x' must be an integer in [0, 2**64)",
        ),
        (
            "dishbot/r1/x",
            {"f": float("nan")},
            0,
            "recording payload for 'dishbot/r1/x' is not JSON: "
            "Out of range float values are not JSON compliant",
        ),
        (
            "dishbot/r1/x",
            {"o": object()},
            0,
            "recording payload for 'dishbot/r1/x' is not JSON: "
            "Object of type object is not JSON serializable",
        ),
    ],
)
def test_write_rejects_bad_messages_and_records_nothing(
    tmp_path: Path, topic: str, payload: object, log_time_ns: object, message: str
) -> None:
    path = tmp_path / "bad.mcap"
    with Recorder(path) as rec:
        with pytest.raises(RecordingError) as err:
            rec.write(topic, payload, log_time_ns=log_time_ns)  # type: ignore[arg-type]
        assert str(err.value) == message
    assert read_messages(path).message_count == 0


def test_writes_after_close_and_a_second_header_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "closed.mcap"
    rec = Recorder(path)
    rec.write_header({"robot_id": "r1"}, {}, log_time_ns=1)
    with pytest.raises(RecordingError, match=r"already has a session header$"):
        rec.write_header({"robot_id": "r1"}, {}, log_time_ns=1)
    rec.close()
    rec.close()
    with pytest.raises(RecordingError, match=r"is closed; open a new Recorder$"):
        rec.write("dishbot/r1/x", {"a": 1}, log_time_ns=0)
    assert read_messages(path).message_count == 1


def test_header_is_on_disk_before_the_recorder_closes(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    with Recorder(path, flush_interval_s=10.0) as rec:
        rec.write_header({"robot_id": "r1"}, {"dataset": 2}, log_time_ns=5)
        deadline = time.monotonic() + 30.0  # the writer's thread gets there in its time (late when loaded)
        while (live := read_messages(path)).header is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert live.truncated
        assert live.header == {"config": {"robot_id": "r1"}, "scene": {"dataset": 2}}
        assert live.cut_after_ns == 5


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "{path}: no such file"),
        (b"", "{path}: empty file, not a recording"),
        (b"hello, world\n", "{path}: not an MCAP file (bad magic)"),
        (b"\x89MCA", "{path}: cut inside the MCAP magic after 4 bytes, nothing recorded"),
    ],
)
def test_reading_bad_files_fails_with_one_line(tmp_path: Path, content: bytes | None, message: str) -> None:
    path = tmp_path / "input.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(RecordingError) as err:
        read_messages(path)
    assert str(err.value) == message.format(path=path)


def test_reading_a_directory_fails_with_one_line(tmp_path: Path) -> None:
    with pytest.raises(RecordingError) as err:
        read_messages(tmp_path)
    assert str(err.value) == f"{tmp_path}: is a directory, not a recording file"


def test_the_health_listener_hears_once_of_a_full_disk_and_once_of_the_next_file_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = SmallDisk(free=10**9)
    monkeypatch.setattr(writer, "open", disk.open, raising=False)
    heard: list[tuple[str, str | None]] = []
    rec = Recorder(tmp_path / "a.mcap", chunk_size=1024, on_health=lambda p, e: heard.append((p.name, e)))
    disk.free = 0
    for i in range(2000):
        rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i)
    deadline = time.monotonic() + 30.0
    while rec.failure is None and time.monotonic() < deadline:  # the recorder's thread meets the full disk
        time.sleep(0.01)
    disk.free = 10**9
    rec.rotate(tmp_path / "b.mcap", header_payload({}, {}), log_time_ns=3000)
    rec.write("dishbot/r1/joints", {"i": 3000}, log_time_ns=3000)
    stats = rec.close()
    assert heard == [("a.mcap", "[Errno 28] No space left on device"), ("b.mcap", None)]
    assert stats.dropped == rec.dropped > 0
    assert rec.failure is None
    assert [m.payload for m in read_messages(tmp_path / "b.mcap") if m.topic.endswith("joints")] == [
        {"i": 3000}
    ]


def test_a_lossless_recorder_keeps_every_message_however_full_its_queue_and_says_when_it_caught_up(
    tmp_path: Path,
) -> None:
    path = tmp_path / "lossless.mcap"
    with Recorder(path, queue_size=8, lossless=True) as rec:
        assert all(rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i) for i in range(5000))
        assert rec.caught_up(30.0)
    stats = rec.stats()
    assert (stats.written, stats.dropped) == (5000, 0)
    assert [m.payload["i"] for m in read_messages(path)] == list(range(5000))
    assert rec.caught_up(0.0)  # closed: nothing is behind


def _wait_until(done: Callable[[], bool]) -> None:
    deadline = time.monotonic() + 30.0
    while not done() and time.monotonic() < deadline:  # the recorder's thread gets there in its time
        time.sleep(0.01)
    assert done()


def test_a_disk_full_for_5_s_costs_only_the_messages_of_those_5_s_and_the_file_goes_on(
    tmp_path: Path,
) -> None:
    heard: list[tuple[str, str | None]] = []
    rec = Recorder(tmp_path / "a.mcap", chunk_size=1024, on_health=lambda p, e: heard.append((p.name, e)))
    rec.disk.fill(30 * 10**9)
    rec.disk.free(35 * 10**9)
    for i in range(6000):  # 60 s at 100 Hz
        rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i * 10**7)
    stats = rec.close()
    full = f"[Errno 28] No space left on device: '{tmp_path / 'a.mcap'}'"
    assert heard == [("a.mcap", full), ("a.mcap", None)]
    assert (stats.dropped, stats.written, stats.files) == (500, 5500, 1)
    got = read_messages(tmp_path / "a.mcap")
    assert not got.truncated
    assert [m.payload["i"] for m in got] == [*range(3000), *range(3500, 6000)]


def test_after_a_failed_write_the_recorder_goes_on_in_a_new_file_of_the_same_stream_once_there_is_room(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = SmallDisk(free=10**9)
    monkeypatch.setattr(writer, "open", disk.open, raising=False)
    heard: list[tuple[str, str | None]] = []
    rec = Recorder(tmp_path / "a.mcap", chunk_size=1024, on_health=lambda p, e: heard.append((p.name, e)))
    file = {"kind": "job", "index": 1, "pid": 1, "previous": None}
    rec.write_header({"k": 1}, {"tray": "robot"}, log_time_ns=0, file=file)
    ms = 10**6
    for i in range(1000):
        rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i * ms)
    _wait_until(lambda: rec.stats().queued == 0)
    disk.free = 0
    for i in range(1000, 2000):
        rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i * ms)
    _wait_until(lambda: rec.failure is not None and rec.stats().queued == 0)
    disk.free = 10**9
    for i in range(2000, 3000):  # room from 2 s on; tried again every 1 s of log time
        rec.write("dishbot/r1/joints", {"i": i}, log_time_ns=i * ms)
    stats = rec.close()
    assert heard == [("a.mcap", "[Errno 28] No space left on device"), ("a-1.mcap", None)]
    assert rec.paths == (tmp_path / "a.mcap", tmp_path / "a-1.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-1.mcap", "a.mcap"]  # no empty tries left
    cut = read_messages(tmp_path / "a.mcap")
    assert cut.truncated
    before = [m.payload["i"] for m in cut if m.topic.endswith("joints")]
    assert before == list(range(len(before)))
    after = list(read_messages(tmp_path / "a-1.mcap"))
    assert after[0].topic == HEADER_TOPIC
    assert after[0].payload == {
        "config": {"k": 1},
        "scene": {"tray": "robot"},
        "file": {**file, "previous": "a.mcap", "continues": True},
    }
    resumed = [int(m.payload["i"]) for m in after[1:]]  # type: ignore[call-overload]
    assert resumed == list(range(resumed[0], 3000))
    assert 2000 <= resumed[0] < 2000 + 1000  # within retry_s of the room coming back
    assert len(before) + len(resumed) + stats.dropped == 3000  # every message in a file or counted lost
    assert stats.files == 2
