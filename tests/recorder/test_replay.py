"""Recorded sessions come back as timelines of driver inputs; fault plans rewrite them deterministically."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import pytest

from daemon.backend import joints_payload, observation_payload
from drivers.errors import SensorFault
from drivers.interfaces import ForceReading, ForceSensor, JointState
from perception.interfaces import Detection, MugObserver, Observation
from recorder import Recorder
from recorder.errors import RecordingError
from replay.errors import ReplayError
from replay.streams import (
    FaultPlan,
    ReplayClock,
    ReplayForceSensor,
    ReplayMugObserver,
    Timeline,
    decode_force,
    decode_joints,
    decode_observation,
)

RecordingFactory = Callable[..., Path]


@pytest.fixture
def timeline(make_recording: RecordingFactory) -> Timeline:
    return Timeline.from_recording(make_recording(seconds=4.0))


def times(timeline: Timeline, stream: str) -> list[float]:
    return [round(x.t_s, 6) for x in timeline.stream(stream)]


def test_timeline_splits_driver_inputs_into_time_ordered_streams(timeline: Timeline) -> None:
    assert {name: len(items) for name, items in timeline.streams.items()} == {
        "joints": 200,
        "force": 200,
        "holding": 0,
        "grasp": 0,
        "observations": 8,
    }
    assert times(timeline, "force")[:3] == [0.001, 0.021, 0.041]
    assert times(timeline, "observations") == [0.002 + 0.5 * k for k in range(8)]
    assert timeline.end_s == pytest.approx(3.981)
    assert not timeline.truncated
    assert timeline.header is not None
    assert timeline.header["config"] == {"robot_id": "r1", "backend": "sim"}
    merged = timeline.merged()
    assert [item.t_s for _, item in merged] == sorted(item.t_s for _, item in merged)
    assert [name for name, _ in merged[:3]] == ["joints", "force", "observations"]


def test_stream_filters_are_key_expressions(make_recording: RecordingFactory) -> None:
    tl = Timeline.from_recording(
        make_recording(seconds=1.0), streams={"driver": "dishbot/r1/input/**", "nothing": "dishbot/r2/**"}
    )
    assert len(tl.stream("driver")) == 102
    assert {x.topic for x in tl.stream("driver")} == {
        "dishbot/r1/input/joints",
        "dishbot/r1/input/force",
        "dishbot/r1/input/observation",
    }
    assert tl.stream("nothing") == ()


def test_invalid_stream_filter_is_refused(make_recording: RecordingFactory) -> None:
    with pytest.raises(ReplayError) as err:
        Timeline.from_recording(make_recording(seconds=1.0), streams={"force": "dishbot//force"})
    assert str(err.value) == "stream 'force': 'dishbot//force' is not a valid Zenoh key expression"


def test_timeline_of_a_cut_recording_ends_at_the_cut(
    make_recording: RecordingFactory, tmp_path: Path
) -> None:
    data = make_recording(seconds=4.0).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    tl = Timeline.from_recording(cut)
    assert tl.truncated
    assert 0 < len(tl.stream("force")) < 200
    assert tl.stream("force")[-1].t_s <= tl.end_s < 3.0


def full_plan(seed: int = 7) -> FaultPlan:
    return (
        FaultPlan()
        .drop("force", 1.5, 2.0)
        .delay("joints", 0.5, 0.6, by_s=0.25)
        .spike("force", 1.0, "force_n", 50.0)
        .corrupt("observations", 3.0, 3.6, "mugs.0.x_m", "garbage")
        .noise("joints", 0.0, 1.0, "position_rad.0", sigma=0.01, seed=seed)
        .cut(3.5, "joints")
    )


def test_fault_plan_gives_the_same_timeline_every_time_and_leaves_the_input_alone(
    timeline: Timeline,
) -> None:
    before = timeline.streams
    first = full_plan().apply(timeline)
    second = full_plan().apply(timeline)
    assert first == second
    assert timeline.streams is before
    assert len(timeline.stream("force")) == 200
    assert first.faults == (
        "drop force [1.5, 2) s",
        "delay joints [0.5, 0.6) s by 0.25 s",
        "spike force.force_n=50.0 at 1 s",
        "corrupt observations.mugs.0.x_m='garbage' [3, 3.6) s",
        "noise joints.position_rad.0 sigma=0.01 seed=7 [0, 1) s",
        "cut joints at 3.5 s",
    )
    assert full_plan(seed=8).apply(timeline) != first


def test_drop_removes_exactly_the_window(timeline: Timeline) -> None:
    out = FaultPlan().drop("force", 1.5, 2.0).apply(timeline)
    assert len(out.stream("force")) == 200 - 25
    assert not [t for t in times(out, "force") if 1.5 <= t < 2.0]
    assert out.stream("joints") == timeline.stream("joints")


def test_delay_moves_inputs_behind_newer_ones(timeline: Timeline) -> None:
    out = FaultPlan().delay("joints", 0.5, 0.6, by_s=0.25).apply(timeline)
    delayed = [x for x in out.stream("joints") if x.log_time_ns != timeline.start_ns + round(x.t_s * 1e9)]
    assert [round(x.t_s, 6) for x in delayed] == [0.75, 0.77, 0.79, 0.81, 0.83]
    arrival = [x.payload["position_rad"][0] for x in out.stream("joints") if 0.7 <= x.t_s < 0.8]  # type: ignore[index]
    assert arrival == pytest.approx([0.35, 0.36, 0.37, 0.25, 0.38, 0.26, 0.39, 0.27])
    assert times(out, "joints") == sorted(times(out, "joints"))


def test_spike_hits_the_first_input_at_or_after_its_time(timeline: Timeline) -> None:
    out = FaultPlan().spike("force", 1.0, "force_n", 50.0).apply(timeline)
    changed = [
        (round(a.t_s, 6), b.payload["force_n"])
        for a, b in zip(timeline.stream("force"), out.stream("force"), strict=True)
        if a != b
    ]
    assert changed == [(1.001, 50.0)]


def test_cut_of_everything_ends_the_session_there(timeline: Timeline) -> None:
    out = FaultPlan().cut(2.0).apply(timeline)
    assert out.end_s == 2.0
    assert all(x.t_s < 2.0 for items in out.streams.values() for x in items)
    assert len(out.stream("force")) == 100


@pytest.mark.parametrize(
    ("plan", "message"),
    [
        (
            lambda: FaultPlan().drop("torque", 0, 1),
            "fault names stream 'torque'; the timeline has: joints, force, holding, grasp, observations",
        ),
        (
            lambda: FaultPlan().drop("force", 9, 10),
            "drop force [9, 10) s: no input in that window (the stream spans 0.001..3.981 s)",
        ),
        (
            lambda: FaultPlan().spike("force", 5.0, "force_n", 0),
            "spike force.force_n=0 at 5 s: the stream has no input at or after 5 s",
        ),
        (
            lambda: FaultPlan().spike("force", 1.0, "torque_n", 0),
            "spike force.torque_n=0 at 1 s: the input at 1.001 s has no field 'torque_n'",
        ),
        (
            lambda: FaultPlan().corrupt("observations", 0, 1, "mugs.3.x_m", None),
            "corrupt observations.mugs.3.x_m=None [0, 1) s: the input at 0.002 s has no field 'mugs.3'",
        ),
        (
            lambda: FaultPlan().noise("observations", 0, 1, "mugs.0.type", sigma=1.0, seed=0),
            "noise observations.mugs.0.type sigma=1 seed=0 [0, 1) s: "
            "cannot add noise to 'big', which is not a number",
        ),
    ],
)
def test_faults_that_miss_or_name_unknown_things_are_refused(
    timeline: Timeline, plan: Callable[[], FaultPlan], message: str
) -> None:
    with pytest.raises(ReplayError) as err:
        plan().apply(timeline)
    assert str(err.value) == message


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: FaultPlan().drop("force", 2.0, 1.0),
            "fault window [2, 1) s is empty; end_s must be after start_s",
        ),
        (
            lambda: FaultPlan().drop("force", -1.0, 1.0),
            "fault start_s must be a time in seconds >= 0, got -1.0",
        ),
        (
            lambda: FaultPlan().delay("force", 0.0, 1.0, by_s=0.0),
            "delay by_s must be a positive number of seconds, got 0.0",
        ),
        (lambda: FaultPlan().cut(float("nan")), "cut at_s must be a time in seconds >= 0, got nan"),
        (
            lambda: FaultPlan().spike("force", 1.0, "a..b", 1),
            "fault field 'a..b' must be a dotted path such as 'force_n' or 'mugs.0.x_m'",
        ),
        (
            lambda: FaultPlan().noise("force", 0, 1, "force_n", sigma=-1.0, seed=0),
            "noise sigma must be a positive number, got -1.0",
        ),
    ],
)
def test_malformed_faults_are_refused_when_built(build: Callable[[], FaultPlan], message: str) -> None:
    with pytest.raises(ReplayError) as err:
        build()
    assert str(err.value) == message


def test_replayed_force_sensor_serves_samples_as_the_clock_passes_them(timeline: Timeline) -> None:
    clock = ReplayClock()
    sensor = ReplayForceSensor(
        timeline.stream("force"), clock, threshold_n=1.0, release_n=0.5, debounce_s=0.03
    )
    assert isinstance(sensor, ForceSensor)
    assert sensor.latest() is None
    assert not sensor.holding()
    clock.set(0.5)
    reading = sensor.latest()
    assert reading is not None
    assert (reading.seq, reading.force_n) == (24, 0.1)
    assert reading.t == pytest.approx(0.481)
    clock.set(1.03)  # above the threshold for 20 ms: not yet debounced
    assert sensor.latest().force_n == 2.0  # type: ignore[union-attr]
    assert not sensor.holding()
    clock.advance(0.02)
    assert sensor.holding()
    clock.set(3.03)
    assert sensor.holding()  # below the release force for 20 ms: still debouncing
    clock.advance(0.02)
    assert not sensor.holding()


def test_force_sensor_goes_quiet_through_a_drop_and_rejects_corrupt_samples(timeline: Timeline) -> None:
    faulted = (
        FaultPlan().drop("force", 1.5, 2.0).corrupt("force", 2.5, 2.55, "force_n", "NaN?").apply(timeline)
    )
    clock = ReplayClock(1.9)
    sensor = ReplayForceSensor(
        faulted.stream("force"), clock, threshold_n=1.0, release_n=0.5, debounce_s=0.03
    )
    assert sensor.latest().t == pytest.approx(1.481)  # type: ignore[union-attr]
    assert sensor.rejected == (
        "force at 2.501 s: force_n is 'NaN?', not a finite number",
        "force at 2.521 s: force_n is 'NaN?', not a finite number",
        "force at 2.541 s: force_n is 'NaN?', not a finite number",
    )
    clock.set(2.545)
    assert sensor.latest().seq == 124  # type: ignore[union-attr]


def test_replayed_observer_serves_the_newest_observation_and_faults_when_the_camera_stops(
    timeline: Timeline,
) -> None:
    faulted = FaultPlan().cut(2.0, "observations").apply(timeline)
    clock = ReplayClock()
    observer = ReplayMugObserver(faulted.stream("observations"), clock, max_age_s=1.0)
    assert isinstance(observer, MugObserver)
    with pytest.raises(SensorFault, match=r"no observation in the 1 s before t=0 s"):
        asyncio.run(observer.observe())
    clock.set(1.2)
    seen = asyncio.run(observer.observe())
    assert seen.t == pytest.approx(1.002)
    assert seen.detections == (Detection("big", 0.1, 0.35, False, 1.5, 0.9, "m0"),)
    clock.set(2.4)
    assert asyncio.run(observer.observe()).t == pytest.approx(1.502)  # the last one before the cut
    clock.advance(0.7)
    with pytest.raises(SensorFault, match=r"before t=3.1 s; the observations stream was dropped, cut"):
        asyncio.run(observer.observe())


def test_replay_clock_only_moves_forward() -> None:
    clock = ReplayClock(1.0)
    with pytest.raises(ReplayError) as err:
        clock.set(0.5)
    assert str(err.value) == "replay clock can only move forward; it is at 1 s, asked for 0.5"
    with pytest.raises(ReplayError):
        clock.advance(-0.1)
    assert clock.now() == 1.0


def test_replay_decodes_what_the_backend_records() -> None:
    joints = JointState(
        t=0.5, names=("a", "b"), position_rad=(0.1, 0.2), velocity_rad_s=(0.0, 1.0), load=(0.5, -0.5)
    )
    assert decode_joints(joints_payload(joints, t=1795311327.41), t=0.5) == joints
    obs = Observation(
        t=3.0,
        detections=(Detection("small", 0.12345, -0.2, True, 3.1, 0.75, "m4"),),
        meta={"source": "truth"},
    )
    assert decode_observation(observation_payload(obs, t=1795311327.41), t=3.0) == obs
    reading = ForceReading(t=1.25, force_n=2.5, raw=512, seq=9)
    assert decode_force({"t": 7.0, "force_n": 2.5, "raw": 512, "seq": 9}, t=1.25) == reading
    with pytest.raises(ValueError, match=r"^position_rad is \[0.1\], not a list of 2 numbers$"):
        decode_joints({**joints_payload(joints, t=0.0), "position_rad": [0.1]}, t=0.5)
    with pytest.raises(ValueError, match=r"^mugs.0.confidence is None, not a finite number$"):
        decode_observation({"mugs": [{**obs.detections[0].to_json(), "confidence": None}]}, t=0.0)


def test_a_recording_without_messages_cannot_be_replayed(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    Recorder(path).close()
    with pytest.raises(RecordingError) as err:
        Timeline.from_recording(path)
    assert str(err.value) == f"{path}: holds no messages to replay"
