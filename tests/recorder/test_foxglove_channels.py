"""A recorded job on the kinematic cell: every channel decodes with the schema stored in the file, and the
Foxglove channels show the cell: a transform tree rooted at ``world``, the arm, one mug entity per detection,
the plan, the logs and events."""

from __future__ import annotations

from collections import Counter, defaultdict
from typing import Any

import pytest

from daemon.app import RunResult
from daemon.backend import SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import StartRequest
from recorder import read_messages
from recorder.foxglove_arm import ArmFrames
from tests.fakes.counter import setup_mugs
from tests.fakes.daemon import serve_daemon
from tests.recorder.foxglove_decode import Decoded, decode_all

ROBOT = "fox"
# Two mugs: a plan of two slots, a mug carried while the other waits on the counter, two on the tray at the
# end; each further mug only repeats the channels' messages.
MUGS = 2


@pytest.fixture(scope="module")
def job(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    """One ``--once`` job of two dataset-1 mugs on the kinematic cell, recorded with Foxglove channels."""
    directory = tmp_path_factory.mktemp("fox")
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})
    request = StartRequest(mugs=setup_mugs(MUGS))
    clock = SimulatedClock()

    async def run() -> RunResult:
        backend = await open_backend(config, sim=SimOptions(world="kinematic", seed=0), clock=clock)
        return await serve_daemon(config, backend, directory, once=request)

    return clock.run(run())


@pytest.fixture(scope="module")
def decoded(job: RunResult) -> dict[str, list[Decoded]]:
    by_topic: dict[str, list[Decoded]] = defaultdict(list)
    for d in decode_all(job.recording):
        by_topic[d.topic].append(d)
    return by_topic


@pytest.mark.slow
def test_a_once_job_is_one_finished_job_file_whose_header_names_what_it_ran(job: RunResult) -> None:
    assert job.end_state == "done"
    assert job.files == (job.recording,)
    assert job.recording.name.endswith("-job.mcap")
    rec = read_messages(job.recording)
    assert not rec.truncated
    header = rec.header
    assert header is not None
    assert header["job"] == {
        "dataset": None,
        "mugs": [{"id": m.mug_id, "type": m.type, "x_m": m.x_m, "y_m": m.y_m} for m in setup_mugs(MUGS)],
        "planner": {"method": "bh", "cost": "upc", "fitness": "rf", "time_limit_s": 1.0, "seed": 0},
        "planner_overrides": {},
        "sim_seed": 0,
    }
    assert header["file"]["kind"] == "job"  # type: ignore[index]


@pytest.mark.slow
def test_every_channel_decodes_with_the_schema_in_the_file(decoded: dict[str, list[Decoded]]) -> None:
    # The kinematic cell's camera is the truth camera's small frame (16 px wide): its depth image and
    # calibration are there as the MuJoCo cell's are.
    schemas = {topic: {d.schema_name for d in items} for topic, items in decoded.items()}
    assert schemas == {
        "/tf": {"foxglove.FrameTransforms"},
        "/camera/depth": {"foxglove.RawImage"},
        "/camera/calibration": {"foxglove.CameraCalibration"},
        "/scene/arm": {"foxglove.SceneUpdate"},
        "/scene/cell": {"foxglove.SceneUpdate"},
        "/scene/mugs": {"foxglove.SceneUpdate"},
        "/scene/plan": {"foxglove.SceneUpdate"},
        "/scene/status": {"foxglove.SceneUpdate"},
        "/log": {"foxglove.Log"},
        "/events": {"foxglove.Log"},
        "session/header": {"dishbot.session_header"},
        **{
            f"dishbot/{ROBOT}/{t}": {f"dishbot.{t.replace('/', '_')}"}
            for t in (
                "state",
                "joints",
                "gripper",
                "detections",
                "plan",
                "events",
                "log",
                "input/joints",
                "input/force",
                "input/holding",
                "input/grasp",
                "input/observation",
                "input/motion",
                "output/follow",
                "output/arm",
                "output/gripper",
            )
        },
    }


@pytest.mark.slow
def test_each_transform_message_is_the_whole_tree_rooted_at_world(decoded: dict[str, list[Decoded]]) -> None:
    arm = ArmFrames.load()
    tf = decoded["/tf"]
    assert len(tf) >= len(decoded[f"dishbot/{ROBOT}/joints"])  # one per joint sample (and one per file)
    for d in tf:
        edges = {(t.parent_frame_id, t.child_frame_id) for t in d.message.transforms}
        children = [child for _, child in edges]
        assert len(children) == len(set(children))  # a tree: one parent per frame
        parent_of = {child: parent for parent, child in edges}
        for frame in children:
            seen = {frame}
            while frame != "world":
                frame = parent_of[frame]  # every frame hangs from world
                assert frame not in seen
                seen.add(frame)
        assert set(children) == {*arm.frames[1:], "camera"}
        assert all(
            t.timestamp.seconds * 10**9 + t.timestamp.nanos == d.log_time_ns for t in d.message.transforms
        )


@pytest.mark.slow
def test_the_transforms_follow_the_joint_samples(decoded: dict[str, list[Decoded]]) -> None:
    arm = ArmFrames.load()
    joints = {d.log_time_ns: d.message for d in decoded[f"dishbot/{ROBOT}/joints"]}
    opening = min(joints)  # on simulated time the file's opening transforms share the first sample's time
    moved = 0
    for d in decoded["/tf"]:
        sample = joints.get(d.log_time_ns)
        if sample is None:
            continue  # the file's opening transforms
        expected = {
            t.child: t
            for t in arm.local_transforms(dict(zip(sample["names"], sample["position_rad"], strict=True)))
        }
        pairs = [
            ((t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w), expected[t.child_frame_id].rotation)
            for t in d.message.transforms
            if t.child_frame_id in expected and t.child_frame_id != "finger_link"
        ]
        if d.log_time_ns == opening and not all(got == pytest.approx(want, abs=1e-9) for got, want in pairs):
            continue  # the opening transforms, not the first sample's
        for got, want in pairs:
            assert got == pytest.approx(want, abs=1e-9)
        moved += 1
    assert moved == len(joints)


@pytest.mark.slow
def test_the_arm_is_drawn_on_its_link_frames(decoded: dict[str, list[Decoded]]) -> None:
    (update,) = decoded["/scene/arm"]  # one file, one opening
    arm = ArmFrames.load()
    entities = {e.id: e for e in update.message.entities}
    links = sorted({v.link for v in arm.visuals})
    assert sorted(entities) == [f"arm/{link}" for link in links]
    for link in links:
        e = entities[f"arm/{link}"]
        assert e.frame_id == link
        assert e.frame_locked
        assert len(e.cubes) == sum(1 for v in arm.visuals if v.link == link and v.shape == "box")


@pytest.mark.slow
def test_one_mug_entity_per_detection(decoded: dict[str, list[Decoded]]) -> None:
    mugs_by_time = {d.log_time_ns: d.message for d in decoded["/scene/mugs"]}
    detections = decoded[f"dishbot/{ROBOT}/detections"]
    assert detections
    for d in detections:
        update = mugs_by_time[d.log_time_ns]
        assert [x.type for x in update.deletions] == [1]  # ALL: the update replaces the mugs drawn before
        on_counter = {e.id for e in update.entities if e.frame_id == "world" and "(" not in e.texts[0].text}
        assert on_counter == {f"mug/{m['id']}" for m in d.message["mugs"]}
        for e in update.entities:
            assert len(e.cylinders) >= 1  # the mug
            assert len(e.cubes) == 1  # its handle


@pytest.mark.slow
def test_the_carried_mug_rides_on_the_gripper_and_placed_mugs_stay_on_the_tray(
    decoded: dict[str, list[Decoded]], job: RunResult
) -> None:
    carried = [e for d in decoded["/scene/mugs"] for e in d.message.entities if e.frame_id == "gripper_link"]
    assert carried
    assert all(e.frame_locked and e.texts[0].text.endswith("(carried)") for e in carried)
    final = decoded["/scene/mugs"][-1].message
    on_tray = sorted(e.id for e in final.entities if "(on tray)" in e.texts[0].text)
    assert on_tray == sorted(f"mug/{m}" for m in job.outcome.placed)
    assert all(len(e.cylinders) == 2 for e in final.entities if "(on tray)" in e.texts[0].text)  # + mark


@pytest.mark.slow
def test_the_plan_shows_the_slots_in_order(decoded: dict[str, list[Decoded]]) -> None:
    plans = list(decoded[f"dishbot/{ROBOT}/plan"])
    updates = {d.log_time_ns: d.message for d in decoded["/scene/plan"]}
    for plan in plans:
        labels = [e.texts[0].text for e in updates[plan.log_time_ns].entities]
        assert labels == [f"{i}: {s['id']}" for i, s in enumerate(plan.message["slots"], start=1)]


@pytest.mark.slow
def test_logs_and_events_are_foxglove_logs_with_levels(decoded: dict[str, list[Decoded]]) -> None:
    logs = decoded["/log"]
    assert [d.message.message.split()[0] for d in logs] == [
        d.message["event"] for d in decoded[f"dishbot/{ROBOT}/log"]
    ]
    events = decoded["/events"]
    assert len(events) == len(decoded[f"dishbot/{ROBOT}/events"])
    levels: Counter[tuple[str, int]] = Counter()
    for fox, raw in zip(events, decoded[f"dishbot/{ROBOT}/events"], strict=True):
        levels[(raw.message["kind"], fox.message.level)] += 1
        assert fox.message.name == "events"
    assert ("mug_placed", 2) in levels  # INFO
    assert all(level != 0 for _, level in levels)


@pytest.mark.slow
def test_the_events_schema_has_every_kind_and_the_mug_and_reason(job: RunResult) -> None:
    rec = read_messages(job.recording)
    schema: Any = rec.schemas[f"dishbot/{ROBOT}/events"]
    assert {"mug_id", "reason", "kind", "state", "t"} <= set(schema["properties"])
    kinds = {str(m.payload["kind"]) for m in rec if m.topic.endswith("/events")}
    assert kinds <= set(schema["properties"]["kind"]["enum"])
    assert {"transition", "cycle_planned", "mug_placed"} <= kinds
