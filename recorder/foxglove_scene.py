"""The cell as Foxglove draws it: messages of Foxglove's well-known schemas, derived from the recording.

``SceneView`` follows the recorded stream (joints, gripper, state, detections, plan, events, log) and turns
it into protobuf messages of Foxglove's well-known schemas, encoded by the Foxglove SDK:

- ``/tf`` (``foxglove.FrameTransforms``), from every ``joints`` sample: the whole tree rooted at ``world``:
  the arm's links from the URDF, the finger from the gripper's aperture, the depth camera.
- ``/scene/arm`` (``foxglove.SceneUpdate``): the URDF's visual boxes, an entity per link, locked to its frame.
- ``/scene/cell``: the counter region, the flip area and the tray (again after a ``scene_set`` event).
- ``/scene/mugs``: one entity per detected mug (a cylinder with its handle, coloured by type, marked when
  upside down), the carried mug moving with the gripper, the mugs set down and those placed on the tray.
- ``/scene/plan``: the planned slots, numbered in placing order; ``/scene/status``: state and counts.
- ``/camera/depth`` (``foxglove.RawImage``, 16UC1 in mm) and ``/camera/calibration``
  (``foxglove.CameraCalibration``): the detections' depth preview, at most ``depth_hz``.
- ``/log`` and ``/events`` (``foxglove.Log``): every ``log`` record; every event, with a level.

The latched topics (arm, cell, mugs, plan, status, the latest transforms, and the calibration once a depth
image gave its size) are repeated at
the start of every file (``opening``), so each file shows the whole scene on its own. Every timestamp inside
a message is the log time the recorder was given for the message it derives from.
"""

from __future__ import annotations

import base64
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final, Protocol, TypeVar

import msgspec
import numpy as np
import structlog
from foxglove import Schema
from foxglove.messages import (
    CameraCalibration,
    Color,
    CubePrimitive,
    CylinderPrimitive,
    Duration,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from description.arm import GripperGeometry
from description.cell import CellLayout
from description.thesis import MugSpec
from perception.calibration import CameraModel
from recorder.foxglove_arm import (
    IDENTITY,
    ArmFrames,
    Matrix,
    Quat,
    Vec3,
    axis_angle,
    matrix,
    multiply,
    pose_of,
)
from recorder.writer import ChannelSpec, Derived
from wire.messages import (
    UNSET,
    BadMessage,
    DepthPreview,
    Detections,
    Event,
    Gripper,
    HeaderScene,
    Joints,
    Message,
    Plan,
    Slot,
    State,
    UnsetType,
    convert,
    header_part,
)
from wire.messages import Log as LogRecord
from wire.schemas import topic_suffix

log = structlog.get_logger(__name__)

WORLD: Final = "world"
CAMERA_FRAME: Final = "camera"
GRIPPER_FRAME: Final = "gripper_link"
FINGER_JOINT: Final = "gripper"

TF: Final = "/tf"
ARM: Final = "/scene/arm"
CELL: Final = "/scene/cell"
MUGS: Final = "/scene/mugs"
PLAN: Final = "/scene/plan"
STATUS: Final = "/scene/status"
DEPTH: Final = "/camera/depth"
CALIBRATION: Final = "/camera/calibration"
LOG: Final = "/log"
EVENTS: Final = "/events"
TOPICS: Final = (TF, ARM, CELL, MUGS, PLAN, STATUS, DEPTH, CALIBRATION, LOG, EVENTS)

_SOURCES: Final = frozenset({"joints", "gripper", "state", "detections", "plan", "events", "log"})
_FOREVER = Duration(sec=0, nsec=0)
_HANDLE_BAR_M = 0.01  # the handle as the planner's handle check models it: a 1 cm bar
_LOG_LEVELS: Final = {
    "debug": LogLevel.Debug,
    "info": LogLevel.Info,
    "warning": LogLevel.Warning,
    "error": LogLevel.Error,
    "exception": LogLevel.Error,
    "critical": LogLevel.Fatal,
}
_ERROR_EVENTS: Final = frozenset({"fault", "bus_lost", "fsr_lost", "tray_collision"})
_WARNING_EVENTS: Final = frozenset(
    {
        "grasp_failed",
        "mug_dropped",
        "mug_given_up",
        "motion_refused",
        "warning",
        "servo_fault",
        "fsr_stale",
        "mug_swapped",
    }
)
_TYPE_COLOURS: Final = ((0.25, 0.5, 0.9), (0.3, 0.75, 0.35), (0.95, 0.6, 0.2), (0.65, 0.4, 0.85))
_ARM_COLOUR = Color(r=0.55, g=0.58, b=0.62, a=1.0)
_MARK_COLOUR = Color(r=0.9, g=0.15, b=0.15, a=1.0)


class _Message(Protocol):
    def encode(self) -> bytes: ...


@functools.cache
def channel(topic: str) -> ChannelSpec:
    """The protobuf channel of one of the Foxglove topics, with the SDK's schema for it."""
    schema = _SCHEMA_OF[topic]()
    return ChannelSpec(topic, "protobuf", schema.name, schema.encoding, bytes(schema.data))


_SCHEMA_OF: Final[dict[str, Callable[[], Schema]]] = {
    TF: FrameTransforms.get_schema,
    ARM: SceneUpdate.get_schema,
    CELL: SceneUpdate.get_schema,
    MUGS: SceneUpdate.get_schema,
    PLAN: SceneUpdate.get_schema,
    STATUS: SceneUpdate.get_schema,
    DEPTH: RawImage.get_schema,
    CALIBRATION: CameraCalibration.get_schema,
    LOG: Log.get_schema,
    EVENTS: Log.get_schema,
}


@dataclass(frozen=True, slots=True)
class MugShape:
    """A mug type's size for drawing: brim diameter, width with the handle, height (m)."""

    diameter_m: float
    width_m: float
    height_m: float
    colour: tuple[float, float, float]


@dataclass(slots=True)
class _Mug:
    mug_id: str
    type: str
    pose: Matrix  # world from the mug frame: origin mid-axis, z base to brim, x towards the handle
    upside_down: bool
    handle_seen: bool = True


@dataclass(slots=True)
class _State:
    """What the view knows of the cell so far (recorder thread only)."""

    positions: dict[str, float] = field(default_factory=dict)
    have_joints: bool = False
    aperture_m: float | None = None
    holding: bool = False
    state: str = ""
    current_mug: str | None = None
    status_text: str = ""
    tray_origin_m: tuple[float, float] = (0.0, 0.0)
    tray_size_m: tuple[float, float] = (0.0, 0.0)
    counter: dict[str, _Mug] = field(default_factory=dict)
    loose: dict[str, _Mug] = field(default_factory=dict)  # set down by the gripper (the flip area)
    placed: dict[str, _Mug] = field(default_factory=dict)
    carried: tuple[_Mug, Matrix] | None = None  # the mug and its pose in the gripper frame
    slots: list[Slot] = field(default_factory=list)
    last_depth_ns: int | None = None
    depth_size: tuple[int, int] | None = None  # the last depth image's width and height


class SceneView:
    """Derives the Foxglove channels from the recorded stream (a ``recording.writer.Deriver``)."""

    def __init__(
        self,
        mug_types: Sequence[MugSpec],
        cell: CellLayout,
        *,
        camera: CameraModel | None = None,
        arm: ArmFrames | None = None,
        depth_hz: float = 1.0,
        gripper: GripperGeometry | None = None,
    ) -> None:
        self._arm = arm or ArmFrames.load()
        self._gripper = gripper or GripperGeometry()
        self._depth_period_ns = round(1e9 / depth_hz)
        names = [m.name for m in mug_types]
        self._shapes = {
            m.name: MugShape(
                m.diameter_mm / 1000.0,
                m.width_mm / 1000.0,
                m.height_mm / 1000.0,
                _TYPE_COLOURS[names.index(m.name) % len(_TYPE_COLOURS)],
            )
            for m in mug_types
        }
        self._cell = cell
        self._camera = _camera(camera) if camera is not None else None
        self._s = _State(
            tray_origin_m=cell.tray.origin_m,
            tray_size_m=(cell.tray.size_mm[0] / 1000.0, cell.tray.size_mm[1] / 1000.0),
        )

    # --- the Deriver protocol ---------------------------------------------------------------------------

    def wants(self, topic: str) -> bool:
        return topic_suffix(topic) in _SOURCES

    def derive(
        self, topic: str, payload: Mapping[str, object] | Message, log_time_ns: int
    ) -> Sequence[Derived]:
        """What one recorded message changes in the views. ``payload``: the decoded message, or its JSON
        object (``events`` and ``log`` as objects: their text shows every key, declared or not);
        ``BadMessage`` when it is not the message its topic carries."""
        kind = topic_suffix(topic)
        t = log_time_ns
        if kind == "joints":
            return self._joints(_as(payload, Joints, kind), t)
        if kind == "gripper":
            return self._gripper_sample(_as(payload, Gripper, kind), t)
        if kind == "state":
            return self._state(_as(payload, State, kind), t)
        if kind == "detections":
            return self._detections(_as(payload, Detections, kind), t)
        if kind == "plan":
            return self._plan(_as(payload, Plan, kind), t)
        if kind == "events":
            plain = payload if isinstance(payload, Mapping) else msgspec.to_builtins(payload)
            return self._event(_as(payload, Event, kind), plain, t)
        if kind == "log":
            plain = payload if isinstance(payload, Mapping) else msgspec.to_builtins(payload)
            return [_derived(LOG, _log_message(_as(payload, LogRecord, kind), plain, t), t)]
        return []

    def opening(self, log_time_ns: int) -> Sequence[Derived]:
        """The scene as it stands, for the start of a new file (or a live client subscribing)."""
        t = log_time_ns
        out = [
            _derived(ARM, self._arm_scene(t), t),
            _derived(CELL, self._cell_scene(t), t),
            _derived(MUGS, self._mugs_scene(t), t),
            _derived(PLAN, self._plan_scene(t), t),
            _derived(STATUS, self._status_scene(t), t),
            _derived(TF, self._transforms(t), t),
        ]
        if self._camera is not None and self._s.depth_size is not None:
            out.append(_derived(CALIBRATION, self._calibration(t), t))
        return out

    def latched(self, topic: str, log_time_ns: int) -> Derived | None:
        """The current message of a latched topic (what a live client gets when it subscribes)."""
        return next((d for d in self.opening(log_time_ns) if d.channel.topic == topic), None)

    # --- per source ----------------------------------------------------------------------------------------

    def _joints(self, joints: Joints, t: int) -> list[Derived]:
        names, positions = joints.names, joints.position_rad
        if len(names) != len(positions):
            raise ValueError("joints payload needs names and position_rad of the same length")
        self._s.positions.update({n: float(q) for n, q in zip(names, positions, strict=True)})
        self._s.have_joints = True
        return [_derived(TF, self._transforms(t), t)]

    def _gripper_sample(self, gripper: Gripper, t: int) -> list[Derived]:
        self._s.aperture_m = float(gripper.aperture_m)
        holding = gripper.holding
        if holding == self._s.holding:
            return []
        self._s.holding = holding
        if holding:
            self._pick_up()
        else:
            self._set_down()
        return [_derived(MUGS, self._mugs_scene(t), t)]

    def _state(self, state: State, t: int) -> list[Derived]:
        s = self._s
        s.state = state.state
        current = state.current_mug
        s.current_mug = current if isinstance(current, str) and current else None
        text = (
            f"{s.state}  placed {state.mugs_placed}/{_count(state.mugs_planned)}"
            f"  failed {_count(state.mugs_failed)}"
        )
        if s.current_mug:
            text += f"  mug {s.current_mug}"
        if text == s.status_text:
            return []
        s.status_text = text
        return [_derived(STATUS, self._status_scene(t), t)]

    def _detections(self, detections: Detections, t: int) -> list[Derived]:
        s = self._s
        s.counter = {}
        carried = s.carried[0].mug_id if s.carried is not None else None
        for i, m in enumerate(detections.mugs):
            mug_id = (m.id if m.id is not UNSET else "") or f"unnamed-{i}"
            if mug_id == carried:
                continue
            upside_down = m.upside_down is True
            s.counter[mug_id] = _Mug(
                mug_id,
                m.type,
                self._upright_pose(
                    m.type,
                    float(m.x_m),
                    float(m.y_m),
                    _or0(m.handle_yaw_rad),
                    upside_down=upside_down,
                ),
                upside_down,
                m.handle_seen is not False,
            )
            s.loose.pop(mug_id, None)
        out = [_derived(MUGS, self._mugs_scene(t), t)]
        preview = detections.depth_preview
        if preview is not UNSET and self._depth_due(t):
            image = _depth_image(preview, t)
            s.depth_size = (preview.width, preview.height)
            s.last_depth_ns = t
            out.append(_derived(DEPTH, image, t))
            if self._camera is not None:
                out.append(_derived(CALIBRATION, self._calibration(t), t))
        return out

    def _plan(self, plan: Plan, t: int) -> list[Derived]:
        self._s.slots = list(plan.slots)
        return [_derived(PLAN, self._plan_scene(t), t)]

    def _event(self, event: Event, payload: Mapping[str, object], t: int) -> list[Derived]:
        s = self._s
        kind = event.kind
        out = [_derived(EVENTS, _event_message(event, payload, t), t)]
        if kind == "mug_placed":
            mug_id = event.mug_id if event.mug_id is not UNSET else ""
            mug = s.counter.pop(mug_id, None) or s.loose.pop(mug_id, None)
            if s.carried is not None and s.carried[0].mug_id == mug_id:
                mug = mug or s.carried[0]
                s.carried = None
            mug_type = mug.type if mug is not None else ""
            s.placed[mug_id] = _Mug(
                mug_id,
                mug_type,
                self._upright_pose(
                    mug_type,
                    _or0(event.x_m),
                    _or0(event.y_m),
                    _or0(event.handle_yaw_rad),
                    upside_down=True,
                ),
                True,
                event.handle_yaw_rad is not UNSET,
            )
            out.append(_derived(MUGS, self._mugs_scene(t), t))
        elif kind == "scene_set":
            tray = header_part(event.scene if event.scene is not UNSET else None, HeaderScene).tray
            size = None if tray is UNSET else tray.size_mm_of()
            if tray is not UNSET and tray.origin_m is not UNSET and len(tray.origin_m) >= 2 and size:
                origin = tray.origin_m
                s.tray_origin_m = (float(origin[0]), float(origin[1]))
                s.tray_size_m = (size[0] / 1000.0, size[1] / 1000.0)
            s.counter, s.loose, s.placed, s.carried, s.slots = {}, {}, {}, None, []
            out += [
                _derived(CELL, self._cell_scene(t), t),
                _derived(MUGS, self._mugs_scene(t), t),
                _derived(PLAN, self._plan_scene(t), t),
            ]
        return out

    # --- the carried mug -----------------------------------------------------------------------------------

    def _pick_up(self) -> None:
        """The gripper closed on the current mug: from now on it moves with the gripper, as it was grasped."""
        s = self._s
        mug_id = s.current_mug
        if mug_id is None or not s.have_joints:
            return
        mug = s.loose.pop(mug_id, None) or s.counter.pop(mug_id, None)
        if mug is None:
            return
        world_gripper = self._arm.world_from(GRIPPER_FRAME, self._joint_positions())
        s.carried = (mug, np.linalg.inv(world_gripper) @ mug.pose)

    def _set_down(self) -> None:
        """The gripper let go: the mug stays where the gripper left it (until the camera sees it again)."""
        s = self._s
        if s.carried is None:
            return
        mug, in_gripper = s.carried
        s.carried = None
        if mug.mug_id in s.placed:
            return
        mug.pose = self._arm.world_from(GRIPPER_FRAME, self._joint_positions()) @ in_gripper
        mug.upside_down = bool(mug.pose[2, 2] < 0.0)
        s.loose[mug.mug_id] = mug

    # --- building the messages -----------------------------------------------------------------------------

    def _joint_positions(self) -> dict[str, float]:
        positions = dict(self._s.positions)
        if self._s.aperture_m is not None:
            positions[FINGER_JOINT] = self._finger_angle(self._s.aperture_m)
        return positions

    def _finger_angle(self, aperture_m: float) -> float:
        g = self._gripper
        s = (g.hinge_offset_m + g.thumb_width_m - aperture_m) / g.finger_length_m
        return math.asin(max(-1.0, min(1.0, s)))

    def _transforms(self, t: int) -> FrameTransforms:
        stamp = _stamp(t)
        transforms = [
            FrameTransform(
                timestamp=stamp,
                parent_frame_id=f.parent,
                child_frame_id=f.child,
                translation=_vector(f.translation),
                rotation=_quaternion(f.rotation),
            )
            for f in self._arm.local_transforms(self._joint_positions())
        ]
        if self._camera is not None:
            xyz, q = self._camera[0]
            transforms.append(
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=WORLD,
                    child_frame_id=CAMERA_FRAME,
                    translation=_vector(xyz),
                    rotation=_quaternion(q),
                )
            )
        return FrameTransforms(transforms=transforms)

    def _arm_scene(self, t: int) -> SceneUpdate:
        stamp = _stamp(t)
        links: dict[str, list[CubePrimitive]] = {}
        cylinders: dict[str, list[CylinderPrimitive]] = {}
        for v in self._arm.visuals:
            pose = _pose(v.xyz, v.rotation)
            if v.shape == "box":
                links.setdefault(v.link, []).append(
                    CubePrimitive(pose=pose, size=_vector(v.size), color=_ARM_COLOUR)
                )
            else:
                cylinders.setdefault(v.link, []).append(
                    CylinderPrimitive(
                        pose=pose, size=_vector(v.size), bottom_scale=1.0, top_scale=1.0, color=_ARM_COLOUR
                    )
                )
        entities = [
            SceneEntity(
                timestamp=stamp,
                frame_id=link,
                id=f"arm/{link}",
                lifetime=_FOREVER,
                frame_locked=True,
                cubes=links.get(link, []),
                cylinders=cylinders.get(link, []),
            )
            for link in self._arm.frames
            if link in links or link in cylinders
        ]
        return SceneUpdate(deletions=[_delete_all(stamp)], entities=entities)

    def _cell_scene(self, t: int) -> SceneUpdate:
        stamp = _stamp(t)
        c = self._cell
        x0, y0, x1, y1 = c.counter_region_m
        (tx, ty), (sx, sy) = self._s.tray_origin_m, self._s.tray_size_m
        fx, fy = c.flip_area_center_m
        counter = SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="cell/counter",
            lifetime=_FOREVER,
            cubes=[
                CubePrimitive(
                    pose=_pose(((x0 + x1) / 2, (y0 + y1) / 2, -0.004), IDENTITY),
                    size=Vector3(x=x1 - x0, y=y1 - y0, z=0.008),
                    color=Color(r=0.82, g=0.72, b=0.55, a=0.6),
                )
            ],
            texts=[_label((x0, y1, 0.02), "counter")],
        )
        flip = SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="cell/flip_area",
            lifetime=_FOREVER,
            cylinders=[
                CylinderPrimitive(
                    pose=_pose((fx, fy, -0.002), IDENTITY),
                    size=Vector3(x=2 * c.flip_area_radius_m, y=2 * c.flip_area_radius_m, z=0.004),
                    bottom_scale=1.0,
                    top_scale=1.0,
                    color=Color(r=0.6, g=0.6, b=0.6, a=0.6),
                )
            ],
            texts=[_label((fx, fy - c.flip_area_radius_m, 0.02), "flip area")],
        )
        corners = [(tx, ty), (tx + sx, ty), (tx + sx, ty + sy), (tx, ty + sy)]
        tray = SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="cell/tray",
            lifetime=_FOREVER,
            cubes=[
                CubePrimitive(
                    pose=_pose((tx + sx / 2, ty + sy / 2, -0.003), IDENTITY),
                    size=Vector3(x=sx, y=sy, z=0.006),
                    color=Color(r=0.35, g=0.4, b=0.45, a=0.5),
                )
            ],
            lines=[
                LinePrimitive(
                    type=LinePrimitiveLineType.LineLoop,
                    pose=_pose((0.0, 0.0, 0.001), IDENTITY),
                    thickness=0.004,
                    points=[Point3(x=x, y=y, z=0.0) for x, y in corners],
                    color=Color(r=0.1, g=0.1, b=0.1, a=1.0),
                )
            ],
            texts=[_label((tx + sx, ty, 0.02), "tray")],
        )
        return SceneUpdate(deletions=[_delete_all(stamp)], entities=[counter, flip, tray])

    def _mugs_scene(self, t: int) -> SceneUpdate:
        stamp = _stamp(t)
        s = self._s
        entities = [self._mug_entity(m, stamp, WORLD, m.pose) for m in s.counter.values()]
        entities += [self._mug_entity(m, stamp, WORLD, m.pose, where="set down") for m in s.loose.values()]
        entities += [self._mug_entity(m, stamp, WORLD, m.pose, where="on tray") for m in s.placed.values()]
        if s.carried is not None:
            mug, in_gripper = s.carried
            entities.append(self._mug_entity(mug, stamp, GRIPPER_FRAME, in_gripper, where="carried"))
        return SceneUpdate(deletions=[_delete_all(stamp)], entities=entities)

    def _mug_entity(
        self, mug: _Mug, stamp: Timestamp, frame: str, pose: Matrix, where: str = ""
    ) -> SceneEntity:
        shape = self._shape(mug.type)
        xyz, q = pose_of(pose)
        r, g, b = shape.colour
        alpha = 1.0 if where != "on tray" else 0.8
        colour = Color(r=r, g=g, b=b, a=alpha)
        handle_length = max(shape.width_m - shape.diameter_m, 0.005)
        handle = _compose((xyz, q), ((shape.diameter_m / 2 + handle_length / 2, 0.0, 0.0), IDENTITY))
        cubes = [
            CubePrimitive(
                pose=_pose(*handle),
                size=Vector3(x=handle_length, y=_HANDLE_BAR_M, z=0.6 * shape.height_m),
                color=Color(r=r, g=g, b=b, a=alpha if mug.handle_seen else 0.35),
            )
        ]
        cylinders = [
            CylinderPrimitive(
                pose=_pose(xyz, q),
                size=Vector3(x=shape.diameter_m, y=shape.diameter_m, z=shape.height_m),
                bottom_scale=1.0,
                top_scale=1.0,
                color=colour,
            )
        ]
        label = mug.mug_id
        if mug.upside_down:
            # A red disc on the base, which faces up when the mug stands on its brim.
            base = _compose((xyz, q), ((0.0, 0.0, -shape.height_m / 2 - 0.002), IDENTITY))
            cylinders.append(
                CylinderPrimitive(
                    pose=_pose(*base),
                    size=Vector3(x=0.8 * shape.diameter_m, y=0.8 * shape.diameter_m, z=0.004),
                    bottom_scale=1.0,
                    top_scale=1.0,
                    color=_MARK_COLOUR,
                )
            )
            label += " upside down"
        if where:
            label += f" ({where})"
        top = pose @ np.array([0.0, 0.0, 0.0, 1.0])
        text_at = (float(top[0]), float(top[1]), float(top[2]) + shape.height_m / 2 + 0.03)
        return SceneEntity(
            timestamp=stamp,
            frame_id=frame,
            id=f"mug/{mug.mug_id}",
            lifetime=_FOREVER,
            frame_locked=frame != WORLD,
            cubes=cubes,
            cylinders=cylinders,
            texts=[_label(text_at, label)],
        )

    def _plan_scene(self, t: int) -> SceneUpdate:
        stamp = _stamp(t)
        entities = []
        for order, slot in enumerate(self._s.slots, start=1):
            shape = self._shape(slot.type)
            x, y = float(slot.x_m), float(slot.y_m)
            r, g, b = shape.colour
            entities.append(
                SceneEntity(
                    timestamp=stamp,
                    frame_id=WORLD,
                    id=f"slot/{slot.id}",
                    lifetime=_FOREVER,
                    cylinders=[
                        CylinderPrimitive(
                            pose=_pose((x, y, 0.002), IDENTITY),
                            size=Vector3(x=shape.diameter_m, y=shape.diameter_m, z=0.004),
                            bottom_scale=1.0,
                            top_scale=1.0,
                            color=Color(r=r, g=g, b=b, a=0.35),
                        )
                    ],
                    texts=[_label((x, y, 0.01), f"{order}: {slot.id}")],
                )
            )
        return SceneUpdate(deletions=[_delete_all(stamp)], entities=entities)

    def _status_scene(self, t: int) -> SceneUpdate:
        stamp = _stamp(t)
        text = self._s.status_text or "starting"
        entity = SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="status",
            lifetime=_FOREVER,
            texts=[_label((0.0, 0.0, 0.6), text, size=14.0)],
        )
        return SceneUpdate(entities=[entity])

    def _calibration(self, t: int) -> CameraCalibration:
        assert self._camera is not None
        _, (width, _height, fx, fy, cx, cy) = self._camera
        assert self._s.depth_size is not None
        w, h = self._s.depth_size  # the depth image's size: the camera's, shrunk for the preview
        scale = w / width
        fx, fy, cx, cy = fx * scale, fy * scale, (cx + 0.5) * scale - 0.5, (cy + 0.5) * scale - 0.5
        return CameraCalibration(
            timestamp=_stamp(t),
            frame_id=CAMERA_FRAME,
            width=w,
            height=h,
            distortion_model="plumb_bob",
            D=[0.0] * 5,
            K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        )

    def _depth_due(self, t: int) -> bool:
        last = self._s.last_depth_ns
        return last is None or t - last >= self._depth_period_ns

    def _shape(self, mug_type: str) -> MugShape:
        return self._shapes.get(mug_type) or next(iter(self._shapes.values()))

    def _upright_pose(
        self, mug_type: str, x_m: float, y_m: float, handle_yaw_rad: float, *, upside_down: bool
    ) -> Matrix:
        rotation = axis_angle((0.0, 0.0, 1.0), handle_yaw_rad)
        if upside_down:
            rotation = multiply(rotation, axis_angle((1.0, 0.0, 0.0), math.pi))
        return matrix((x_m, y_m, self._shape(mug_type).height_m / 2), rotation)


def _camera(model: CameraModel) -> tuple[tuple[Vec3, Quat], tuple[int, int, float, float, float, float]]:
    """The camera's pose (world from the optical frame: z forward, x right, y down) and intrinsics."""
    k = model.intrinsics
    return pose_of(np.asarray(model.world_from_camera, dtype=np.float64)), (
        k.width,
        k.height,
        k.fx,
        k.fy,
        k.cx,
        k.cy,
    )


def _depth_image(preview: DepthPreview, t: int) -> RawImage:
    width, height = preview.width, preview.height
    data = base64.b64decode(preview.data)
    if len(data) != 2 * width * height:
        raise ValueError(f"depth preview has {len(data)} bytes for {width}x{height} pixels")
    return RawImage(
        timestamp=_stamp(t),
        frame_id=CAMERA_FRAME,
        width=width,
        height=height,
        encoding="16UC1",
        step=2 * width,
        data=data,
    )


def _log_message(record: LogRecord, fields: Mapping[str, object], t: int) -> Log:
    """A log record as Foxglove's log line: its event, then every other field the record has (``fields``,
    its JSON object: a record is open), in its order."""
    skip = {"event", "level", "timestamp", "logger"}
    detail = " ".join(f"{k}={v}" for k, v in fields.items() if k not in skip)
    return Log(
        timestamp=_stamp(t),
        level=_LOG_LEVELS.get(record.level, LogLevel.Unknown),
        message=f"{record.event} {detail}".strip(),
        name=record.logger if record.logger is not UNSET else "dishbot",
    )


def _event_message(event: Event, fields: Mapping[str, object], t: int) -> Log:
    if event.kind in _ERROR_EVENTS:
        level = LogLevel.Error
    elif event.kind in _WARNING_EVENTS:
        level = LogLevel.Warning
    else:
        level = LogLevel.Info
    return Log(timestamp=_stamp(t), level=level, message=describe_event(event, fields), name="events")


def describe_event(event: Event, fields: Mapping[str, object]) -> str:
    """One line for an ``events`` message: its kind, the mug and the reason first, then the rest of its
    fields (``fields``, its JSON object: a device's event carries keys of its own), in its order."""
    if event.kind == "transition":
        source, dest, trigger = (None if v is UNSET else v for v in (event.source, event.dest, event.trigger))
        return f"transition {source} -> {dest} ({trigger})"
    text = event.kind
    if event.mug_id:
        text += f" {event.mug_id}"
    if event.reason:
        text += f": {event.reason}"
    skip = {"kind", "mug_id", "reason", "t", "state", "scene"}
    rest = " ".join(f"{k}={v}" for k, v in fields.items() if k not in skip)
    state = "" if event.state is UNSET else event.state
    return f"{text}{' ' + rest if rest else ''}{f' [{state}]' if state else ''}"


M = TypeVar("M", bound=Message)


def _as(payload: Mapping[str, object] | Message, kind: type[M], name: str) -> M:
    """A source message as its declared type (``BadMessage`` naming the field when it is not one)."""
    if isinstance(payload, kind):
        return payload
    if isinstance(payload, Message):
        raise BadMessage(f"{name}: a {type(payload).__name__}, not a {kind.__name__}")
    return convert(payload, kind, name=name)


def _count(value: int | UnsetType) -> int:
    """An optional count, 0 when the message leaves it out."""
    return 0 if isinstance(value, UnsetType) else value


def _or0(value: float | UnsetType) -> float:
    """An optional number, 0 when the message leaves it out."""
    return 0.0 if isinstance(value, UnsetType) else float(value)


def _derived(topic: str, message: _Message, t: int) -> Derived:
    return Derived(channel(topic), message.encode(), t)


def _stamp(t_ns: int) -> Timestamp:
    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def _vector(v: Vec3) -> Vector3:
    return Vector3(x=v[0], y=v[1], z=v[2])


def _quaternion(q: Quat) -> Quaternion:
    return Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])


def _pose(xyz: Vec3, q: Quat) -> Pose:
    return Pose(position=_vector(xyz), orientation=_quaternion(q))


def _compose(a: tuple[Vec3, Quat], b: tuple[Vec3, Quat]) -> tuple[Vec3, Quat]:
    return pose_of(matrix(*a) @ matrix(*b))


def _label(xyz: Vec3, text: str, *, size: float = 11.0) -> TextPrimitive:
    return TextPrimitive(
        pose=_pose(xyz, IDENTITY),
        billboard=True,
        font_size=size,
        scale_invariant=True,
        color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
        text=text,
    )


def _delete_all(stamp: Timestamp) -> SceneEntityDeletion:
    return SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.All)
