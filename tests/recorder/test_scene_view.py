"""The Foxglove scene derived from dishbot's messages: the depth image at its configured size, mugs drawn as
detected (upside down marked), the carried mug moving with the gripper, and the arm's frames from the URDF
as Pinocchio computes them."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.config import load_config
from daemon.hardware import scene_view
from daemon.messages import depth_preview
from recorder.foxglove_arm import ArmFrames, UrdfError
from recorder.foxglove_scene import channel, describe_event
from tests.recorder.foxglove_decode import message_class
from wire.messages import Detections, Event, convert

T = 1_790_000_000_000_000_000
JOINTS = ("shoulder_turn", "shoulder_lift", "elbow_lift", "wrist_lift", "wrist_turn")


def decode(derived: Any) -> Any:
    spec = derived.channel
    return message_class(spec.schema_name, spec.schema_data).FromString(derived.data)


def by_topic(out: Any) -> dict[str, Any]:
    return {d.channel.topic: decode(d) for d in out}


def detection(
    mug_id: str, mug_type: str, x: float, y: float, *, upside_down: bool = False
) -> dict[str, object]:
    return {
        "id": mug_id,
        "type": mug_type,
        "x_m": x,
        "y_m": y,
        "upside_down": upside_down,
        "handle_yaw_rad": 0.5,
        "handle_seen": True,
        "confidence": 0.9,
    }


def test_the_depth_image_has_the_configured_cameras_shape_in_16_bit_millimetres() -> None:
    config = load_config(overrides={"camera": {"width": 320, "height": 240}})
    view = scene_view(config)
    depth = np.full((60, 80), 1.25, dtype=np.float32)  # the observer's preview of a 320x240 frame
    depth[0, 0] = np.nan  # no reading
    payload = Detections(t=0.0, mugs=[], meta={}, depth_preview=depth_preview(depth))
    out = by_topic(view.derive("dishbot/r1/detections", payload, T))
    image = out["/camera/depth"]
    assert (image.width, image.height, image.encoding, image.step) == (80, 60, "16UC1", 160)
    assert image.frame_id == "camera"
    pixels = np.frombuffer(image.data, dtype="<u2").reshape(60, 80)
    assert pixels[0, 0] == 0
    assert pixels[5, 5] == 1250
    calibration = out["/camera/calibration"]
    assert (calibration.width, calibration.height) == (80, 60)
    # the full-size focal length, over 4
    f = (
        (240 / 2) / math.tan(math.radians(config.cell.camera.fovy_deg) / 2) / 4
    )  # the full-size focal length / 4
    assert list(calibration.K) == pytest.approx([f, 0, 39.5, 0, f, 29.5, 0, 0, 1])


def test_depth_images_come_at_most_at_depth_hz() -> None:
    view = scene_view(load_config(), depth_hz=0.5)
    payload = Detections(t=0.0, mugs=[], depth_preview=depth_preview(np.ones((12, 16), np.float32)))
    times = [T + k * 500_000_000 for k in range(9)]  # every 0.5 s for 4 s
    images = [
        t for t in times if "/camera/depth" in by_topic(view.derive("dishbot/r1/detections", payload, t))
    ]
    assert images == [T, T + 2_000_000_000, T + 4_000_000_000]


def test_one_entity_per_detected_mug_coloured_by_type_and_marked_when_upside_down() -> None:
    view = scene_view(load_config())
    mugs = [detection("m1", "big", 0.1, 0.45), detection("m2", "small", -0.1, 0.5, upside_down=True)]
    out = by_topic(view.derive("dishbot/r1/detections", {"t": 0.0, "mugs": mugs, "meta": {}}, T))
    entities = {e.id: e for e in out["/scene/mugs"].entities}
    assert sorted(entities) == ["mug/m1", "mug/m2"]
    big, small = entities["mug/m1"], entities["mug/m2"]
    assert big.cylinders[0].size.x == pytest.approx(0.091)  # the catalogue's brim diameter
    assert big.cylinders[0].size.z == pytest.approx(0.106)
    assert big.cylinders[0].pose.position.z == pytest.approx(0.053)  # standing on the counter
    assert (big.cylinders[0].color.r, big.cylinders[0].color.b) != (
        small.cylinders[0].color.r,
        small.cylinders[0].color.b,
    )
    assert len(big.cylinders) == 1
    assert len(small.cylinders) == 2  # the red mark on its base
    assert small.texts[0].text == "m2 upside down"
    handle = big.cubes[0].pose.position
    r = 0.091 / 2 + (0.120 - 0.091) / 2  # the handle's middle, out from the axis towards the handle yaw
    assert (handle.x, handle.y) == pytest.approx((0.1 + r * math.cos(0.5), 0.45 + r * math.sin(0.5)))


def test_the_grasped_mug_moves_with_the_gripper_then_stays_where_it_was_set_down() -> None:
    view = scene_view(load_config())
    q: dict[str, Any] = {"t": 0.0, "names": list(JOINTS), "position_rad": [0.3, -0.8, 1.6, 0.4, -1.57]}
    view.derive("dishbot/r1/joints", q, T)
    view.derive(
        "dishbot/r1/state",
        {"state": "side_grasp.close", "mugs_total": 1, "mugs_placed": 0, "current_mug": "m1", "t": 0.0},
        T,
    )
    view.derive("dishbot/r1/detections", {"t": 0.0, "mugs": [detection("m1", "big", 0.3, 0.45)]}, T)
    out = by_topic(view.derive("dishbot/r1/gripper", {"t": 0.0, "aperture_m": 0.09, "holding": True}, T + 1))
    (carried,) = out["/scene/mugs"].entities
    assert carried.frame_id == "gripper_link"
    assert carried.frame_locked
    assert carried.texts[0].text == "m1 (carried)"
    # Where the mug is in the gripper frame is where it was in the world when grasped.
    arm = ArmFrames.load()
    world_gripper = arm.world_from("gripper_link", dict(zip(JOINTS, q["position_rad"], strict=True)))
    p = carried.cylinders[0].pose.position
    assert (world_gripper @ np.array([p.x, p.y, p.z, 1.0]))[:3] == pytest.approx([0.3, 0.45, 0.053])
    moved: dict[str, Any] = {"t": 0.0, "names": list(JOINTS), "position_rad": [-0.9, -0.8, 1.6, 0.4, -1.57]}
    view.derive("dishbot/r1/joints", moved, T + 2)
    out = by_topic(view.derive("dishbot/r1/gripper", {"t": 0.0, "aperture_m": 0.12, "holding": False}, T + 3))
    (loose,) = out["/scene/mugs"].entities
    assert loose.frame_id == "world"
    assert loose.texts[0].text == "m1 (set down)"
    turned = arm.world_from("gripper_link", dict(zip(JOINTS, moved["position_rad"], strict=True)))
    expected = turned @ np.linalg.inv(world_gripper) @ np.array([0.3, 0.45, 0.053, 1.0])
    p = loose.cylinders[0].pose.position
    assert [p.x, p.y, p.z] == pytest.approx(expected[:3])


def test_placed_mugs_stay_on_the_tray_and_a_new_scene_clears_them() -> None:
    view = scene_view(load_config())
    view.derive("dishbot/r1/detections", {"t": 0.0, "mugs": [detection("m1", "small", 0.1, 0.45)]}, T)
    placed = {
        "kind": "mug_placed",
        "state": "place.release",
        "t": 0.0,
        "mug_id": "m1",
        "x_m": 0.5,
        "y_m": 0.0,
    }
    out = by_topic(view.derive("dishbot/r1/events", placed, T + 1))
    (mug,) = out["/scene/mugs"].entities
    assert mug.texts[0].text == "m1 upside down (on tray)"
    assert (mug.cylinders[0].pose.position.x, mug.cylinders[0].pose.position.y) == pytest.approx((0.5, 0.0))
    assert out["/events"].message.startswith("mug_placed m1 ")
    scene = {"tray": {"origin_m": [0.3, -0.25], "size_mm": [475, 520]}, "mugs": [], "dataset": 4}
    out = by_topic(
        view.derive("dishbot/r1/events", {"kind": "scene_set", "state": "idle", "scene": scene}, T + 2)
    )
    assert list(out["/scene/mugs"].entities) == []
    tray = next(e for e in out["/scene/cell"].entities if e.id == "cell/tray")
    assert tray.cubes[0].size.x == pytest.approx(0.475)
    assert tray.cubes[0].pose.position.x == pytest.approx(0.3 + 0.475 / 2)


def test_events_become_one_line_logs_with_a_level() -> None:
    view = scene_view(load_config())
    given_up = {"kind": "mug_given_up", "state": "detect", "t": 1.0, "mug_id": "m10", "reason": "no motion"}
    log = by_topic(view.derive("dishbot/r1/events", given_up, T))["/events"]
    assert log.message == "mug_given_up m10: no motion [detect]"
    assert log.level == 3  # WARNING
    fault = by_topic(view.derive("dishbot/r1/events", {"kind": "fault", "reason": "BusLost: gone"}, T))[
        "/events"
    ]
    assert fault.level == 4  # ERROR
    transition = {"kind": "transition", "source": "idle", "dest": "detect", "trigger": "start"}
    assert describe_event(convert(transition, Event), transition) == "transition idle -> detect (start)"
    # A device's event: its own keys, in its order, after the kind.
    lost = {"port": "/dev/ttyUSB0", "kind": "bus_lost", "device": "servo bus", "t": 2.0, "state": "idle"}
    assert describe_event(convert(lost, Event), lost) == "bus_lost port=/dev/ttyUSB0 device=servo bus [idle]"


def test_log_records_keep_their_level_and_fields() -> None:
    view = scene_view(load_config())
    record = {"event": "grasp_held", "level": "warning", "timestamp": "x", "servo_id": 6}
    log = by_topic(view.derive("dishbot/r1/log", record, T))["/log"]
    assert (log.level, log.message) == (3, "grasp_held servo_id=6")
    assert (log.timestamp.seconds, log.timestamp.nanos) == (T // 10**9, T % 10**9)


def test_channels_carry_the_sdks_well_known_schemas() -> None:
    assert channel("/tf").schema_name == "foxglove.FrameTransforms"
    assert channel("/tf").schema_encoding == channel("/tf").message_encoding == "protobuf"
    assert channel("/camera/depth").schema_name == "foxglove.RawImage"


def test_the_urdf_chain_gives_pinocchios_poses() -> None:
    from planning.arm import ArmModel

    model = ArmModel.load()
    arm = ArmFrames.load()
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = rng.uniform(-1.5, 1.5, 5)
        position, rotation = model.fk(q)
        pose = arm.world_from("grasp_point", dict(zip(JOINTS, q, strict=True)))
        assert pose[:3, 3] == pytest.approx(position, abs=1e-12)
        assert pose[:3, :3] == pytest.approx(rotation, abs=1e-12)


def test_the_tree_is_read_parents_first_with_every_link() -> None:
    arm = ArmFrames.load()
    assert arm.root == "world"
    assert arm.frames[:3] == ("world", "base_link", "turret_link")
    assert {"finger_link", "grasp_point"} <= set(arm.frames)
    assert [j.name for j in arm.joints if j.kind == "revolute"] == [*JOINTS, "gripper"]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("<robot><link name='a'/><link name='b'/></robot>", "expected one root link, found ['a', 'b']"),
        (
            "<robot><link name='a'/><link name='b'/><joint name='j' type='planar'><parent link='a'/>"
            "<child link='b'/></joint></robot>",
            "joint 'j' has type 'planar'; supported: revolute, continuous, prismatic, fixed",
        ),
        (
            "<robot><link name='a'/><link name='b'/><joint name='j' type='fixed'><parent link='a'/>"
            "<child link='b'/><origin xyz='0 0'/></joint></robot>",
            "joint 'j': '0 0' is not three numbers",
        ),
    ],
)
def test_a_bad_urdf_is_refused_in_one_line(tmp_path: Path, body: str, message: str) -> None:
    path = tmp_path / "arm.urdf"
    path.write_text(body)
    with pytest.raises(UrdfError) as err:
        ArmFrames.load(path)
    assert str(err.value) == f"{path}: {message}"


def test_the_foxglove_layout_in_docs_shows_channels_the_recordings_have() -> None:
    import json
    import re

    from recorder.foxglove_scene import TOPICS
    from wire.schemas import schema_for

    layout = json.loads((Path(__file__).resolve().parents[2] / "docs" / "foxglove-layout.json").read_text())
    panels = set(layout["configById"])

    def leaves(node: Any) -> list[str]:
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
    assert {p.split("!")[0] for p in panels} == {"3D", "Image", "StateTransitions", "Plot", "RosOut"}
    for config in layout["configById"].values():
        for topic in (*config.get("topics", {}), config.get("topicToRender")):
            if topic:
                assert topic in TOPICS
        for key in ("imageTopic", "calibrationTopic"):
            if key in config.get("imageMode", {}):
                assert config["imageMode"][key] in TOPICS
        for path in config.get("paths", []):
            topic, field = re.match(r"^([^.]+)\.(\w+)", path["value"]).groups()  # type: ignore[union-attr]
            assert topic.startswith("dishbot/dishbot/")  # the default robot_id
            assert field in schema_for(topic)["properties"]  # type: ignore[operator]


def test_the_status_label_shows_the_counts_as_the_state_message_has_them() -> None:
    view = scene_view(load_config())
    state = {"state": "flip.turn", "mugs_total": 5, "mugs_planned": 4, "mugs_placed": 1, "t": 0.0}
    out = by_topic(view.derive("dishbot/r1/state", {**state, "mugs_failed": 0, "current_mug": "m3"}, T))
    assert out["/scene/status"].entities[0].texts[0].text == "flip.turn  placed 1/4  failed 0  mug m3"
    # counts the message leaves out are shown as 0; a message that is not a state is refused, naming the field
    out = by_topic(
        view.derive("dishbot/r1/state", {"state": "done", "mugs_total": 5, "mugs_placed": 4, "t": 1.0}, T)
    )
    assert out["/scene/status"].entities[0].texts[0].text == "done  placed 4/0  failed 0"
    with pytest.raises(ValueError, match="state: mugs_placed: missing"):
        view.derive("dishbot/r1/state", {"state": "done", "mugs_total": 5, "t": 1.0}, T)
