"""Every message dishbot publishes on Zenoh and records to MCAP, declared once as a ``msgspec.Struct``.

One type per topic (what follows ``dishbot/<robot_id>/``; ``TOPICS`` maps each to its type). From that one
declaration come the three things a message needs:

- the decoder: ``decode(data, Type)`` (or ``decode_topic(topic, data)``) checks the JSON bytes against the
  type and builds it, or raises ``BadMessage`` with one line naming the message and the field;
- the encoder: ``encode(message)`` writes the bytes the daemon puts on Zenoh and in the recording (the same
  bytes for both);
- the JSON Schema the recorder stores with each channel (``wire.schemas``, generated from the type).

Fields are declared in the order the daemon writes them, so a decoded message encodes to the very bytes it
came from (a test checks it against a recording made before these types existed). A field that a message may
leave out is ``X | UnsetType = UNSET`` (left out again when encoded); one that is written as ``null`` is
``X | None``. Numbers that a producer may write as an integer are ``Number`` (``int | float``), so
that ``130`` stays ``130``. Fields a later version adds are allowed on decoding (``additionalProperties``
in the schema) and ignored by older readers.

The daemon's producers build these structs (``daemon.messages``, ``daemon.recorded``). Two topics are open
by nature: ``events`` (each kind has its own detail, and a driver's device event carries the driver's own
keys, before ``kind``) and ``log`` (a structlog record: whatever the call named). Their types declare every
field dishbot writes, for typed reading. The job's events of a fixed detail are built as a tagged union by
``kind`` (``JobEvents``); transitions, device events and log records as mappings (``encode`` takes a mapping
too, keeping the producer's key order: ``Payload``).
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Mapping
from typing import Annotated, Any, Final, Literal, TypeVar

import msgspec
from msgspec import UNSET, UnsetType

from statechart.chart import LEAVES

Number = int | float  # JSON has one number type; a producer may write 130 where 130.5 could be


def doc(text: str, **schema: object) -> msgspec.Meta:
    """A field's description (and any further JSON Schema keywords) for the generated schema."""
    return msgspec.Meta(description=text, extra_json_schema=schema or None)


WallT = Annotated[Number, doc("wall clock at publication, Unix seconds")]
DeviceT = Annotated[Number, doc("the driver's own clock (monotonic or simulated), seconds")]


class Message(msgspec.Struct, kw_only=True):
    """A message on one topic; the base of every declared message."""


class BadMessage(ValueError):
    """A payload that is not the message its topic carries; one line naming the message and the field."""


# --- telemetry ----------------------------------------------------------------------------------------------


class State(Message, kw_only=True):
    state: Annotated[str, doc("the chart's leaf state", enum=list(LEAVES))]
    mugs_total: Annotated[int, doc("mugs known: on the counter and on the tray")]
    mugs_planned: Annotated[int, doc("mugs with a tray slot")] | UnsetType = UNSET
    mugs_placed: Annotated[int, doc("mugs on the tray")]
    mugs_failed: Annotated[int, doc("mugs given up")] | UnsetType = UNSET
    current_mug: Annotated[str | None, doc("the mug being handled")] | UnsetType = UNSET
    transitions: Annotated[int, doc("transitions since the daemon started")] | UnsetType = UNSET
    t: WallT


class Joints(Message, kw_only=True):
    t: WallT
    t_device: DeviceT | UnsetType = UNSET
    names: Annotated[list[str], doc("joint names, base to wrist")]
    position_rad: Annotated[list[Number], doc("joint angles, rad")]
    velocity_rad_s: Annotated[list[Number], doc("joint velocities, rad/s")] | UnsetType = UNSET
    load: Annotated[list[Number], doc("servo load, fraction of full torque (signed)")] | UnsetType = UNSET


# Who read the arm's joints (``daemon.recorded.joint_reader``): a replay hands each reader its own samples.
JointReader = Annotated[
    str,
    doc(
        "who read the arm: job (the job's own read) or telemetry (the joints poll); left out by recordings "
        "made before it was recorded"
    ),
]


class InputJoints(Joints, kw_only=True):
    """``input/joints``: a read of the arm as its reader got it (unrounded), with the session's time of it."""

    t_read: DeviceT | UnsetType = UNSET
    reader: JointReader | UnsetType = UNSET


class Gripper(Message, kw_only=True):
    t: WallT
    t_device: DeviceT | UnsetType = UNSET
    aperture_m: Annotated[Number, doc("distance between thumb and finger, m")]
    load: Annotated[Number, doc("gripper servo load, fraction of full torque")] | UnsetType = UNSET
    force_n: Annotated[Number | None, doc("FSR pad force, N")] | UnsetType = UNSET
    raw: Annotated[int | None, doc("FSR ADC reading")] | UnsetType = UNSET
    seq: Annotated[int | None, doc("FSR sample number")] | UnsetType = UNSET
    holding: Annotated[bool, doc("the debounced force says a mug is held")]


class Detection(Message, kw_only=True):
    id: Annotated[str, doc("the job's id of the mug (m1, m2, ...; empty before association)")] | UnsetType = (
        UNSET
    )
    type: Annotated[str, doc("mug type from the catalogue")]
    x_m: Annotated[Number, doc("mug axis, world x, m")]
    y_m: Annotated[Number, doc("mug axis, world y, m")]
    upside_down: Annotated[bool, doc("the mug stands on its brim")] | UnsetType = UNSET
    handle_yaw_rad: Annotated[Number, doc("direction of the handle about world z, rad")] | UnsetType = UNSET
    handle_seen: (
        Annotated[bool, doc("the camera saw the handle (else its direction is a guess)")] | UnsetType
    ) = UNSET
    confidence: Annotated[Number, doc("detector confidence, 0-1")] | UnsetType = UNSET


class DepthPreview(Message, kw_only=True):
    width: Annotated[int, doc("pixels across")]
    height: Annotated[int, doc("pixels down")]
    encoding: Literal["uint16_mm_le_base64"]
    data: Annotated[
        str, doc("depth in mm, unsigned 16-bit little-endian, row-major, base64 (0 = no reading)")
    ]


ObservationT = Annotated[Number, doc("time of the depth frame (the observer's clock), s")]
Mugs = Annotated[list[Detection], doc("the mugs seen on the counter")]
Meta = Annotated[dict[str, Any], doc("what produced the observation (source, frame id)")]


class Detections(Message, kw_only=True):
    t: ObservationT
    t_device: DeviceT | UnsetType = UNSET
    mugs: Mugs
    meta: Meta | UnsetType = UNSET
    depth_preview: DepthPreview | UnsetType = UNSET


class PlacedMug(Message, kw_only=True):
    id: Annotated[str, doc("mug id")] | UnsetType = UNSET
    type: Annotated[str, doc("mug type")] | UnsetType = UNSET
    x_mm: Annotated[Number, doc("footprint corner on the tray, tray x, mm")] | UnsetType = UNSET
    y_mm: Annotated[Number, doc("footprint corner on the tray, tray y, mm")] | UnsetType = UNSET
    rotated: Annotated[bool, doc("footprint turned by 90 degrees")] | UnsetType = UNSET
    order: Annotated[int, doc("position in the placing order")] | UnsetType = UNSET
    brim_mm: (
        Annotated[list[Number] | None, doc("brim centre on the tray, [x, y], tray coordinates, mm")]
        | UnsetType
    ) = UNSET
    handle_yaw_rad: (
        Annotated[Number | None, doc("where the arm leaves the handle, tray frame, rad (0 = +x)")] | UnsetType
    ) = UNSET


class Slot(Message, kw_only=True):
    id: Annotated[str, doc("mug id")]
    type: Annotated[str, doc("mug type")]
    x_m: Annotated[Number, doc("mug axis in the slot, world x, m")]
    y_m: Annotated[Number, doc("mug axis in the slot, world y, m")]
    rotated: Annotated[bool, doc("footprint turned by 90 degrees")] | UnsetType = UNSET


class OutOfReach(Message, kw_only=True):
    id: Annotated[str, doc("mug id")]
    reason: Annotated[str, doc("why the arm cannot take it")]


class Plan(Message, kw_only=True):
    method: Annotated[str, doc("placement method used")] | UnsetType = UNSET
    heuristic: Annotated[str, doc("packing heuristic")] | UnsetType = UNSET
    sort: Annotated[str | None, doc("mug order heuristic")] | UnsetType = UNSET
    fitness: Annotated[str, doc("fitness function")] | UnsetType = UNSET
    cost_function: Annotated[str, doc("cost function")] | UnsetType = UNSET
    seed: Annotated[int, doc("random seed")] | UnsetType = UNSET
    wall_time_s: Annotated[Number, doc("planning time, s")] | UnsetType = UNSET
    placed: Annotated[list[PlacedMug], doc("the mugs given a slot, tray coordinates")] | UnsetType = UNSET
    unplaced: Annotated[list[str], doc("mugs that do not fit")] | UnsetType = UNSET
    n: Annotated[int, doc("mugs placed")] | UnsetType = UNSET
    A: Annotated[Number, doc("tray area used, mm²")] | UnsetType = UNSET
    E: Annotated[Number, doc("energy estimate, J")] | UnsetType = UNSET
    t: Annotated[Number, doc("wall clock at publication, Unix seconds")] | UnsetType = UNSET
    s: Annotated[int, doc("sorting score")] | UnsetType = UNSET
    cost: Annotated[Number, doc("the cost minimised")] | UnsetType = UNSET
    optimal: Annotated[bool | None, doc("proven optimal (null: no solver said)")] | UnsetType = UNSET
    upper_bound: Annotated[int | None, doc("upper bound on the mugs that fit")] | UnsetType = UNSET
    gap: Annotated[int | None, doc("upper bound minus mugs placed")] | UnsetType = UNSET
    status: Annotated[str, doc("solver status")] | UnsetType = UNSET
    evaluations: Annotated[int, doc("layouts evaluated")] | UnsetType = UNSET
    notes: Annotated[list[str], doc("planner remarks")] | UnsetType = UNSET
    out_of_reach: (
        Annotated[list[OutOfReach], doc("mugs left out of the plan: the arm cannot take them")] | UnsetType
    ) = UNSET
    slots: Annotated[list[Slot], doc("the slots in placing order, world frame")]
    t_plan_s: (
        Annotated[Number, doc("the plan's time estimate: the cycles and the computation, s")] | UnsetType
    ) = UNSET


# --- events -------------------------------------------------------------------------------------------------

# Every ``kind`` the job, the backends, the drivers and a fault file put on ``events`` (README, "Zenoh key
# space"). A new kind goes here: the schema's enumeration is this list.
EVENT_KINDS: Final = (
    "transition",
    "fault",
    "grasp_failed",
    "mug_dropped",
    "mug_found",
    "mug_given_up",
    "mug_swapped",
    "mug_placed",
    "cycle_planned",
    "motion_refused",
    "out_of_reach",
    "slot_dropped",
    "counter_changed",
    "scene_set",
    "tray_collision",
    "warning",
    "servo_fault",
    "servo_warning",
    "servo_health_ok",
    "servo_recovered",
    "bus_lost",
    "bus_restored",
    "gripper_overload_recovered",
    "fsr_lost",
    "fsr_stale",
    "fsr_restored",
    "recording_failed",
    "recording_restored",
    "connection_lost",
    "connection_restored",
    "fault_injected",
    "fault_ended",
)

U = UnsetType


class Event(Message, kw_only=True):
    """One entry of ``events``: its ``kind``, where the chart was, when, and the kind's detail (every field
    but ``kind`` is the detail of some kinds only)."""

    kind: Annotated[str, doc("what happened", enum=list(EVENT_KINDS))]
    state: Annotated[str, doc("the chart's state when it happened")] | U = UNSET
    t: WallT | U = UNSET
    t_device: DeviceT | U = UNSET
    mug_id: (
        Annotated[str, doc("the mug concerned (grasp_failed, mug_dropped, mug_placed, mug_given_up, ...)")]
        | U
    ) = UNSET
    reason: (
        Annotated[str, doc("why (fault, mug_given_up, motion_refused, out_of_reach, servo events)")] | U
    ) = UNSET
    detail: Annotated[str, doc("out_of_reach: the planner's own words")] | U = UNSET
    trigger: Annotated[str, doc("transition: the event that fired it")] | U = UNSET
    source: Annotated[str, doc("transition: the state left")] | U = UNSET
    dest: Annotated[str, doc("transition: the state entered")] | U = UNSET
    grasp_held: Annotated[bool, doc("transition: the grasp's outcome")] | U = UNSET
    needs_plan: Annotated[bool, doc("transition: the tray needs a new plan")] | U = UNSET
    has_next_mug: Annotated[bool, doc("transition: another mug is ready")] | U = UNSET
    mug_found: Annotated[bool, doc("transition: the lost mug was seen again")] | U = UNSET
    x_m: Annotated[Number, doc("mug_placed: the slot, world x, m; mug_found: where the mug was seen")] | U = (
        UNSET
    )
    y_m: Annotated[Number, doc("mug_placed: the slot, world y, m; mug_found: where the mug was seen")] | U = (
        UNSET
    )
    handle_yaw_rad: (
        Annotated[Number, doc("mug_placed: where the handle lands, rad (when the camera saw it)")] | U
    ) = UNSET
    retry: Annotated[bool, doc("cycle_planned: a new cycle for a mug that was lost")] | U = UNSET
    duration_s: Annotated[Number, doc("cycle_planned: duration of the planned cycle, s")] | U = UNSET
    energy_j: Annotated[Number, doc("cycle_planned: energy of the planned cycle, J")] | U = UNSET
    came: Annotated[list[str], doc("counter_changed: mugs that appeared")] | U = UNSET
    went: Annotated[list[str], doc("counter_changed: mugs that disappeared")] | U = UNSET
    slot_for: Annotated[str, doc("mug_swapped: the mug whose slot was handed over")] | U = UNSET
    message: Annotated[str, doc("warning: what is wrong")] | U = UNSET
    scene: Annotated[dict[str, Any], doc("scene_set: the new scene (mugs, tray, dataset)")] | U = UNSET
    device: Annotated[str, doc("device events: which device (servo bus, fsr)")] | U = UNSET
    port: Annotated[str, doc("device events: the serial port")] | U = UNSET
    servo_id: Annotated[int, doc("servo events: the servo's bus id")] | U = UNSET
    servo: Annotated[int, doc("servo_fault, servo_warning, servo_health_ok: the servo's bus id")] | U = UNSET
    value: Annotated[Number, doc("servo_fault, servo_warning: the value read")] | U = UNSET
    limit: Annotated[Number, doc("servo_fault, servo_warning: the limit it is near or past")] | U = UNSET
    error_bit: Annotated[str | None, doc("servo_fault, servo_warning: the servo's own error bit")] | U = UNSET
    faults: Annotated[str, doc("servo_fault: the fault bits, as text")] | U = UNSET
    grip_limit: Annotated[Number, doc("gripper_overload_recovered: the grip's load limit")] | U = UNSET
    error: Annotated[str, doc("device events: the driver's error")] | U = UNSET
    force_n: Annotated[Number, doc("mug_dropped (fsr), tray_collision: force, N")] | U = UNSET
    a: Annotated[str, doc("tray_collision: first body")] | U = UNSET
    b: Annotated[str, doc("tray_collision: second body")] | U = UNSET
    position_m: Annotated[list[Number], doc("tray_collision: contact point, world frame, m")] | U = UNSET
    t_sim: Annotated[Number, doc("tray_collision: simulated time, s")] | U = UNSET
    event: Annotated[str, doc("tray_collision: the collision's own name")] | U = UNSET
    path: Annotated[str, doc("recording_failed, recording_restored: the recording file")] | U = UNSET
    dropped: Annotated[int, doc("recording_failed: messages the recording lost so far")] | U = UNSET
    peers: Annotated[int, doc("connection_lost, connection_restored: peers connected")] | U = UNSET
    routers: Annotated[int, doc("connection_lost, connection_restored: routers connected")] | U = UNSET
    fault: Annotated[str, doc("fault_injected, fault_ended: the fault file's kind")] | U = UNSET
    fired_at_s: Annotated[Number, doc("fault_injected: when, s after the job's start")] | U = UNSET
    ended_at_s: Annotated[Number, doc("fault_ended: when, s after the job's start")] | U = UNSET
    index: Annotated[int, doc("fault_injected, fault_ended: the fault's place in its file")] | U = UNSET
    still_acting: Annotated[list[int], doc("fault_ended: faults still holding the device")] | U = UNSET


class EventKind(Message, kw_only=True):
    """Only an event's ``kind`` (its other fields are not read): for a reader that must act on the kind of
    an event whose other fields may not be what ``Event`` declares."""

    kind: str


# --- the job's events by kind: a tagged union (``kind`` the tag) ------------------------------------------
#
# What the job and the daemon write on ``events`` with a detail of its kind's own, built as one of these:
# ``kind`` is the tag (written first), then the chart's state and the times (``Services.event`` fills them),
# then the kind's detail in the order the job writes it. ``events``' declared type, and so its schema, stays
# the flat ``Event`` above: a driver's device event writes its own keys before ``kind``, a transition's detail
# is the firing unit's guard values, and Foxglove's message paths want one object's properties; every field of
# every kind here is a field of ``Event`` of the same type (a test holds them to it). ``decode_event`` reads
# an event as its kind's struct, and any other (a transition, a device's, a fault file's, an unknown kind
# from another version) as the flat ``Event``.


class JobEvent(Message, kw_only=True, tag_field="kind"):
    """An event of one of the job's kinds; ``state``, ``t`` and ``t_device`` are filled when published."""

    state: str | U = UNSET
    t: Number | U = UNSET
    t_device: Number | U = UNSET


class MugGivenUpEvent(JobEvent, kw_only=True, tag="mug_given_up"):
    mug_id: str
    reason: str


class MugFoundEvent(JobEvent, kw_only=True, tag="mug_found"):
    mug_id: str
    x_m: Number
    y_m: Number


class MotionRefusedEvent(JobEvent, kw_only=True, tag="motion_refused"):
    mug_id: str
    reason: str


class MugSwappedEvent(JobEvent, kw_only=True, tag="mug_swapped"):
    slot_for: str
    mug_id: str
    reason: str


class CyclePlannedEvent(JobEvent, kw_only=True, tag="cycle_planned"):
    mug_id: str
    retry: bool
    duration_s: Number
    energy_j: Number


class SceneSetEvent(JobEvent, kw_only=True, tag="scene_set"):
    scene: dict[str, Any]


class RecordingFailedEvent(JobEvent, kw_only=True, tag="recording_failed"):
    path: str
    error: str
    dropped: int


class RecordingRestoredEvent(JobEvent, kw_only=True, tag="recording_restored"):
    path: str


class FaultEvent(JobEvent, kw_only=True, tag="fault"):
    reason: str


class WarningEvent(JobEvent, kw_only=True, tag="warning"):
    message: str


class OutOfReachEvent(JobEvent, kw_only=True, tag="out_of_reach"):
    mug_id: str
    reason: str
    detail: str


class SlotDroppedEvent(JobEvent, kw_only=True, tag="slot_dropped"):
    mug_id: str
    reason: str


class CounterChangedEvent(JobEvent, kw_only=True, tag="counter_changed"):
    came: list[str]
    went: list[str]


class MugDroppedEvent(JobEvent, kw_only=True, tag="mug_dropped"):
    mug_id: str


class GraspFailedEvent(JobEvent, kw_only=True, tag="grasp_failed"):
    mug_id: str


class MugPlacedEvent(JobEvent, kw_only=True, tag="mug_placed"):
    mug_id: str
    x_m: Number
    y_m: Number
    handle_yaw_rad: Number | U = UNSET


class ConnectionLostEvent(JobEvent, kw_only=True, tag="connection_lost"):
    peers: int
    routers: int


class ConnectionRestoredEvent(JobEvent, kw_only=True, tag="connection_restored"):
    peers: int
    routers: int


JobEvents = (
    MugGivenUpEvent
    | MugFoundEvent
    | MotionRefusedEvent
    | MugSwappedEvent
    | CyclePlannedEvent
    | SceneSetEvent
    | RecordingFailedEvent
    | RecordingRestoredEvent
    | FaultEvent
    | WarningEvent
    | OutOfReachEvent
    | SlotDroppedEvent
    | CounterChangedEvent
    | MugDroppedEvent
    | GraspFailedEvent
    | MugPlacedEvent
    | ConnectionLostEvent
    | ConnectionRestoredEvent
)
JOB_EVENTS: Final[tuple[type[JobEvent], ...]] = JobEvents.__args__
_JOB_EVENT_TAGS: Final = frozenset(str(k.__struct_config__.tag) for k in JOB_EVENTS)


def decode_event(data: bytes | str) -> JobEvents | Event:
    """An ``events`` payload as its kind's struct (one of ``JobEvents``), or as the flat ``Event`` when its
    kind has none (a transition, a device's event, a fault file's, a kind from another version) or it does
    not have its kind's fields; ``BadMessage`` when it is not an event at all."""
    event = decode(data, Event, name="events")
    if event.kind in _JOB_EVENT_TAGS:
        try:
            kinded: JobEvents = msgspec.json.decode(data, type=JobEvents)
        except msgspec.ValidationError:
            return event
        return kinded
    return event


# Where the job was when an input from outside it came (``daemon.recorded.JobPosition``): a replay sends it
# again when its job is at the same place.
AtState = Annotated[str, doc("the job's state when it came")]
AtTransitions = Annotated[
    int, doc("transitions since the job's start (the start's own included) when it came")
]
AtDeviceCommands = Annotated[int, doc("device commands (moves, openings, closes, looks, stops) the job gave")]


class DeviceEventInput(Event, kw_only=True):
    """``input/device_event``: a driver's event as the daemon heard it, with the job's position then."""

    at_state: AtState | U = UNSET
    at_transitions: AtTransitions | U = UNSET
    at_device_commands: AtDeviceCommands | U = UNSET
    t_read: DeviceT


class Log(Message, kw_only=True):
    """A log record relayed on ``log``: structlog's event and level and whatever the call named (open)."""

    event: Annotated[str, doc("the structlog event name")]
    level: Annotated[str, doc("the logging method: debug, info, warning, error, exception, critical")]
    timestamp: Annotated[str, doc("when it was logged, as the log renderer writes it")] | U = UNSET
    logger: Annotated[str, doc("the logger's name")] | U = UNSET
    process: Annotated[str, doc("'planning' for records relayed from the planning worker")] | U = UNSET
    mug_id: Annotated[str, doc("the mug the record is about")] | U = UNSET
    state: Annotated[str, doc("the chart state the record is about")] | U = UNSET
    error: Annotated[str, doc("an error's text")] | U = UNSET
    reason: Annotated[str, doc("why")] | U = UNSET
    exception: Annotated[str, doc("the exception logged with the record: its type and message")] | U = UNSET
    traceback: Annotated[str, doc("that exception's traceback, as Python prints it")] | U = UNSET
    t: Annotated[Number, doc("the session's clock when the daemon published the record, s")] | U = UNSET


# --- the driver boundary (recorded, not published): what a replay hands the job again ----------------------

ErrorText = Annotated[str, doc("the driver's error when the call failed: its type, a colon, its message")]
ErrorClass = Annotated[str, doc("the error's type: its module and name (a replay raises the same again)")]
ErrorServo = Annotated[int, doc("the servo a ServoFault names")]
ErrorBits = Annotated[list[str], doc("the error bits a ServoFault names")]
ErrorPort = Annotated[str, doc("the port a BusLost names")]


Cancelled = Annotated[bool, doc("the call was cancelled (the job left the state)")]


class Failure(Message, kw_only=True):
    """The fields of a driver call that raised or was cancelled (``daemon.messages.failure_fields``), as the
    calls' messages carry them."""

    cancelled: Cancelled | U = UNSET
    error: ErrorText | U = UNSET
    error_class: ErrorClass | U = UNSET
    error_servo_id: ErrorServo | U = UNSET
    error_bits: ErrorBits | U = UNSET
    error_port: ErrorPort | U = UNSET


class Force(Message, kw_only=True):
    t: WallT | U = UNSET
    t_device: DeviceT | U = UNSET
    t_read: DeviceT | U = UNSET
    force_n: Annotated[Number, doc("FSR pad force, N")]
    raw: Annotated[int, doc("FSR ADC reading")] | U = UNSET
    seq: Annotated[int, doc("FSR sample number")] | U = UNSET


class Holding(Message, kw_only=True):
    holding: Annotated[bool, doc("the debounced force says a mug is held")]
    t_read: DeviceT | U = UNSET


class Grasp(Message, kw_only=True):
    held: Annotated[bool, doc("the gripper's close says it holds the mug")]
    force_n: Annotated[Number, doc("pad force when the close ended, N")] | U = UNSET
    aperture_m: Annotated[Number, doc("aperture when the close ended, m")] | U = UNSET
    reason: Annotated[str, doc("why the close ended")] | U = UNSET
    force_threshold_n: Annotated[Number, doc("the force the close was asked to reach, N")] | U = UNSET
    min_aperture_m: Annotated[Number, doc("the aperture below which the close gives up, m")] | U = UNSET
    t_start: DeviceT | U = UNSET
    t_end: DeviceT | U = UNSET


class Observation(Message, kw_only=True):
    """``input/observation``: what the observer returned (unrounded), and when the look began and ended."""

    t: ObservationT
    t_device: DeviceT | U = UNSET
    mugs: Mugs
    meta: Meta | U = UNSET
    t_start: DeviceT | U = UNSET
    t_end: DeviceT | U = UNSET


class ReadFailed(Message, kw_only=True):
    """``input/joints_failed``, ``input/gripper_failed``, ``input/health_failed``: a read that raised."""

    t: WallT | U = UNSET
    t_read: DeviceT
    error: ErrorText
    error_class: ErrorClass | U = UNSET
    error_servo_id: ErrorServo | U = UNSET
    error_bits: ErrorBits | U = UNSET
    error_port: ErrorPort | U = UNSET
    reader: JointReader | U = UNSET  # (``input/joints_failed`` only)


class CallFailed(Message, kw_only=True):
    """``input/grasp_failed``, ``input/observe_failed``: a close or a look that raised or was cancelled."""

    t: WallT | U = UNSET
    force_threshold_n: Annotated[Number, doc("the force the close was asked to reach, N")] | U = UNSET
    min_aperture_m: Annotated[Number, doc("the aperture below which the close gives up, m")] | U = UNSET
    t_start: DeviceT
    t_end: DeviceT
    cancelled: Cancelled | U = UNSET
    error: ErrorText | U = UNSET
    error_class: ErrorClass | U = UNSET
    error_servo_id: ErrorServo | U = UNSET
    error_bits: ErrorBits | U = UNSET
    error_port: ErrorPort | U = UNSET


MotionCall = Literal["plan_cycle", "plan_for_slot", "plan_move"]


class Motion(Message, kw_only=True):
    """``input/motion``: one call the job made to its motion planner and its answer (``wire.motion``)."""

    call: MotionCall
    args_digest: Annotated[str, doc("SHA-256 (first 32 hex digits) over the call's arguments (wire.motion)")]
    result: (
        Annotated[
            dict[str, Any], doc("the plan: a cycle plan, {mug, plan} or a trajectory (float64 base64 arrays)")
        ]
        | U
    ) = UNSET
    refused: Annotated[str, doc("MotionRefused: why no motion exists")] | U = UNSET
    blockers: Annotated[list[str], doc("MotionRefused: the mugs that made it impossible")] | U = UNSET
    error: ErrorText | U = UNSET
    error_class: ErrorClass | U = UNSET
    error_servo_id: ErrorServo | U = UNSET
    error_bits: ErrorBits | U = UNSET
    error_port: ErrorPort | U = UNSET


class Command(Message, kw_only=True):
    """``input/command``: an operator's command as it came, the daemon's reply and where the job was."""

    t: WallT
    t_device: DeviceT | U = UNSET
    verb: Annotated[str, doc("the command's verb (cmd/<verb>); status queries are not kept")]
    payload: Annotated[str, doc("the command's JSON payload as received (UTF-8, undecodable bytes replaced)")]
    many: Annotated[bool, doc("the query named robots by wildcard")] | U = UNSET
    reply: Annotated[dict[str, Any], doc("the daemon's reply")] | U = UNSET
    at_state: AtState | U = UNSET
    at_transitions: AtTransitions | U = UNSET
    at_device_commands: AtDeviceCommands | U = UNSET


class Follow(Message, kw_only=True):
    """``output/follow``: a trajectory the job gave the arm, and how it went."""

    label: Annotated[str, doc("what the trajectory is for (approach, lift, transit, ...)")]
    points: Annotated[int, doc("trajectory points")] | U = UNSET
    duration_s: Annotated[Number, doc("the trajectory's planned duration, s")] | U = UNSET
    end_rad: Annotated[list[Number], doc("the goal joint positions, rad")] | U = UNSET
    t_start: DeviceT
    t_end: DeviceT
    cancelled: Cancelled | U = UNSET
    error: ErrorText | U = UNSET
    error_class: ErrorClass | U = UNSET
    error_servo_id: ErrorServo | U = UNSET
    error_bits: ErrorBits | U = UNSET
    error_port: ErrorPort | U = UNSET


class ArmCommand(Message, kw_only=True):
    action: Annotated[str, doc("stop (hold here) or relax (torque off)")]
    t_start: DeviceT | U = UNSET


class GripperCommand(Message, kw_only=True):
    action: Annotated[str, doc("open or stop")]
    aperture_m: Annotated[Number | None, doc("the opening asked for, m (null: fully)")] | U = UNSET
    t_start: DeviceT | U = UNSET
    t_end: DeviceT | U = UNSET
    cancelled: Cancelled | U = UNSET
    error: ErrorText | U = UNSET
    error_class: ErrorClass | U = UNSET
    error_servo_id: ErrorServo | U = UNSET
    error_bits: ErrorBits | U = UNSET
    error_port: ErrorPort | U = UNSET


class SessionHeader(Message, kw_only=True):
    """``session/header``: the first message of every file."""

    config: Annotated[dict[str, Any], doc("the effective configuration (dishbot config show)")]
    scene: Annotated[dict[str, Any], doc("the scene as the file opened (tray, mugs, dataset)")]
    clock: Annotated[dict[str, Any], doc("the session clock's source and rate")] | U = UNSET
    job: (
        Annotated[
            dict[str, Any] | None,
            doc("what the job in this file ran: dataset or mugs, planner settings, seeds"),
        ]
        | U
    ) = UNSET
    file: Annotated[dict[str, Any], doc("kind (job or idle), writer pid, the file before it")] | U = UNSET


# Typed views of the header's open documents (``config``, ``scene``, ``job``, ``file`` stay JSON objects in
# the declaration, so that a later key is kept byte for byte): what readers take from them, every field
# optional (``header_part`` reads one, an empty view when it is not one).


class HeaderFile(Message, kw_only=True):
    """``session/header``'s ``file``: which file of the session this is."""

    kind: Annotated[str, doc("job or idle")] | U = UNSET
    index: Annotated[int, doc("the file's number in its writer's process, from 1")] | U = UNSET
    pid: Annotated[int, doc("the writing process")] | U = UNSET
    previous: Annotated[str | None, doc("the file before it (null: the first)")] | U = UNSET
    continues: Annotated[bool, doc("it goes on after a file whose writing failed")] | U = UNSET


class HeaderMug(Message, kw_only=True):
    """A mug a ``start`` command listed (``job.mugs``)."""

    id: Annotated[str, doc("mug id")] | U = UNSET
    type: Annotated[str, doc("mug type")] | U = UNSET
    x_m: Annotated[Number, doc("world x, m")] | U = UNSET
    y_m: Annotated[Number, doc("world y, m")] | U = UNSET


class HeaderPlanner(Message, kw_only=True):
    """``job.planner``: the effective planner settings."""

    method: Annotated[str, doc("placement method")] | U = UNSET
    cost: Annotated[str, doc("cost function")] | U = UNSET
    fitness: Annotated[str, doc("fitness function")] | U = UNSET
    time_limit_s: Annotated[Number, doc("time limit, s")] | U = UNSET
    seed: Annotated[int, doc("random seed")] | U = UNSET


class HeaderJob(Message, kw_only=True):
    """``session/header``'s ``job``: what the job in the file ran."""

    dataset: Annotated[int | None, doc("the dataset set out")] | U = UNSET
    mugs: Annotated[list[HeaderMug] | None, doc("the mugs the start command listed")] | U = UNSET
    planner: Annotated[dict[str, Any], doc("the effective planner settings")] | U = UNSET
    planner_overrides: Annotated[dict[str, Any], doc("the start command's planner settings")] | U = UNSET
    sim_seed: Annotated[int | None, doc("the simulated cell's seed")] | U = UNSET
    carried: (
        Annotated[
            dict[str, Any],
            doc("what the job carried over from the jobs before: on_tray, tray_mugs, counter"),
        ]
        | U
    ) = UNSET


class HeaderTray(Message, kw_only=True):
    """A scene's tray. The backend writes its size in mm; the kinematic world's own scene, which overrides
    it in a kinematic cell's header, in m (``size_m``). Each is optional, so that neither empties the view
    (``header_part`` reads a document that does not fit as an empty view): ``size_mm_of`` reads either."""

    origin_m: Annotated[list[Number], doc("the tray's corner, world x and y, m")] | U = UNSET
    size_mm: Annotated[list[Number], doc("the tray's size, mm")] | U = UNSET
    size_m: Annotated[list[Number], doc("the tray's size, m (the kinematic world's scene)")] | U = UNSET

    def size_mm_of(self) -> tuple[float, float] | None:
        """The tray's size in mm, from whichever unit the scene wrote; None when neither is there."""
        if not isinstance(self.size_mm, UnsetType) and len(self.size_mm) >= 2:
            return float(self.size_mm[0]), float(self.size_mm[1])
        if not isinstance(self.size_m, UnsetType) and len(self.size_m) >= 2:
            return float(self.size_m[0]) * 1000.0, float(self.size_m[1]) * 1000.0
        return None


class HeaderScene(Message, kw_only=True):
    """``session/header``'s ``scene`` (and a ``scene_set`` event's): the cell as the file or job opened."""

    backend: Annotated[str, doc("the backend's name")] | U = UNSET
    tray: HeaderTray | U = UNSET
    dataset: Annotated[int | None, doc("the dataset on the counter")] | U = UNSET


class HeaderConfig(Message, kw_only=True):
    """What readers take from ``session/header``'s ``config``."""

    robot_id: Annotated[str, doc("the robot's id")] | U = UNSET
    dataset: Annotated[int | None, doc("the configured dataset")] | U = UNSET


class HeaderClock(Message, kw_only=True):
    """``session/header``'s ``clock``: the session clock's source and, when simulated, where it started."""

    source: Annotated[str, doc("wall or simulated")] | U = UNSET
    wall_start: Annotated[Number, doc("the clock's start on the wall clock, Unix seconds")] | U = UNSET


class HeaderSlot(Message, kw_only=True):
    """One of ``job.carried``'s ``on_tray`` slots: a mug an earlier job placed
    (``planning.interfaces.TraySlot`` as JSON)."""

    mug_id: Annotated[str, doc("the job's id of the mug")] | U = UNSET
    type: Annotated[str, doc("mug type")] | U = UNSET
    x_m: Annotated[Number, doc("the slot's axis, world x, m")] | U = UNSET
    y_m: Annotated[Number, doc("the slot's axis, world y, m")] | U = UNSET
    rotated: Annotated[bool, doc("footprint turned by 90 degrees")] | U = UNSET
    handle_yaw_rad: Annotated[Number | None, doc("where the handle points, world yaw, rad")] | U = UNSET


class HeaderSceneMug(Message, kw_only=True):
    """One of ``scene.mugs`` in an older simulated recording's header: the simulated world's own table of
    a mug (its ids are the world's, not the job's)."""

    id: Annotated[str, doc("the simulated world's id of the mug")] | U = UNSET
    type: Annotated[str, doc("mug type")] | U = UNSET
    x_m: Annotated[Number, doc("world x, m")] | U = UNSET
    y_m: Annotated[Number, doc("world y, m")] | U = UNSET
    where: Annotated[str, doc("counter, tray or gripper")] | U = UNSET
    upside_down: Annotated[bool, doc("the mug stands on its brim")] | U = UNSET
    handle_yaw_rad: Annotated[Number, doc("direction of the handle about world z, rad")] | U = UNSET


H = TypeVar(
    "H",
    HeaderFile,
    HeaderJob,
    HeaderPlanner,
    HeaderScene,
    HeaderConfig,
    HeaderClock,
    HeaderSlot,
    HeaderSceneMug,
)


_log = logging.getLogger(__name__)


def header_part(document: object, kind: type[H]) -> H:
    """One of the header's documents as its view; an empty view when it is missing or not one.

    A document that is there but does not fit the view is logged as a warning naming the view and what did not
    fit: read as empty, it would otherwise pass for "missing" (a scene whose tray did not fit once made every
    kinematic replay of datasets 2-6 stand in dataset 1, silently)."""
    if document is None or document is UNSET:
        return kind()
    if not isinstance(document, Mapping):
        _log.warning(
            "recording header: %s is a %s, not a table; read as empty", kind.__name__, type(document).__name__
        )
        return kind()
    try:
        return msgspec.convert(document, type=kind, strict=True)
    except msgspec.ValidationError as e:
        _log.warning("recording header: %s does not fit (%s); read as empty", kind.__name__, e)
        return kind()


# --- views: the part of a message that a reader takes, whichever topic or source it came from -------------
#
# No topic carries these (no schema is generated from them, ``TOPICS`` does not name them): each is the few
# fields of one or more declared messages that one reader compares or times by, so that a recorded payload
# and a live request (or an older recording's rebuilt entry) are read as one typed value. Unknown keys are
# ignored as on every message; ``view`` reads one.


class FollowAsked(Message, kw_only=True):
    """What a move asked the arm (``output/follow``'s label and goal), recorded or asked now."""

    label: Annotated[str, doc("what the trajectory is for")]
    end_rad: Annotated[list[Number], doc("the goal joint positions, rad (empty: no point)")] = []


class OpenAsked(Message, kw_only=True):
    """What an ``output/gripper`` command asked: its action and, for an opening, how far."""

    action: Annotated[str, doc("open or stop")]
    aperture_m: Annotated[Number | None, doc("the opening asked for, m (null: fully)")] = None


class CloseAsked(Message, kw_only=True):
    """What a close asked (``input/grasp``, ``input/grasp_failed``, or a close asked now): its force."""

    force_threshold_n: Annotated[Number | None, doc("the force the close was asked to reach, N")] = None


class Started(Message, kw_only=True):
    """When a device command began (``t_start`` of ``output/*``, ``input/grasp``, ``input/observation``,
    ``input/grasp_failed``, ``input/observe_failed``), on the driver's clock."""

    t_start: DeviceT | U = UNSET


class InputPosition(Message, kw_only=True):
    """Where an input from outside the job fell (``input/command``, ``input/device_event``, and a device
    event that a replay rebuilds from an older recording's ``events``): the driver's time of it (``t_read``,
    else ``t_device``) and the job's position then (``at_transitions``, ``at_device_commands``)."""

    t_read: DeviceT | U = UNSET
    t_device: DeviceT | U = UNSET
    at_transitions: AtTransitions | U = UNSET
    at_device_commands: AtDeviceCommands | U = UNSET


V = TypeVar("V", FollowAsked, OpenAsked, CloseAsked, Started, InputPosition)


def view(payload: Mapping[str, object] | Message, kind: type[V], *, name: str = "") -> V:
    """The part ``kind`` of a payload (a mapping, or a message's fields); ``BadMessage`` (one line naming
    ``name`` and the field) when the payload does not have it."""
    if isinstance(payload, kind):
        return payload
    if isinstance(payload, Message):
        payload = plain(payload)
    return convert(payload, kind, name=name)


# --- the replies to ``cmd/<verb>`` (Zenoh queries; not recorded) -------------------------------------------


class ReplyRecording(Message, kw_only=True):
    """``status``'s ``recording``: whether recording works, the file and error of a failure, messages lost."""

    ok: Annotated[bool, doc("recording works")] | U = UNSET
    path: Annotated[str | None, doc("the file being written, or the one that failed")] | U = UNSET
    error: Annotated[str, doc("why writing failed")] | U = UNSET
    dropped: Annotated[int, doc("messages lost")] | U = UNSET


class Reply(Message, kw_only=True):
    """A daemon's reply to ``cmd/<verb>``: ``robot_id``, ``ok`` and the ``error`` of a refusal; for
    ``status`` (and the verbs that change the state) the ``state`` message's fields, the job's summary, the
    commands allowed now and the recording's health. What a client reads of it: it prints the reply as it
    came."""

    robot_id: Annotated[str, doc("the robot that answered")] | U = UNSET
    ok: Annotated[bool, doc("the command was accepted")] | U = UNSET
    error: Annotated[str, doc("why it was refused")] | U = UNSET
    state: Annotated[str, doc("the chart's leaf state")] | U = UNSET
    mugs_total: Annotated[int, doc("mugs known")] | U = UNSET
    mugs_planned: Annotated[int, doc("mugs with a tray slot")] | U = UNSET
    mugs_placed: Annotated[int, doc("mugs on the tray")] | U = UNSET
    mugs_failed: Annotated[int, doc("mugs given up")] | U = UNSET
    current_mug: Annotated[str | None, doc("the mug being handled")] | U = UNSET
    allowed: Annotated[list[str], doc("the commands the state allows now")] | U = UNSET
    recording: ReplyRecording | U = UNSET


def reply_of(document: Mapping[str, object]) -> Reply:
    """A reply as the client reads it; one that is not a reply reads as refused, naming the field."""
    try:
        return msgspec.convert(document, type=Reply, strict=True)
    except msgspec.ValidationError as e:
        robot = document.get("robot_id")
        return Reply(
            robot_id=robot if isinstance(robot, str) else UNSET,
            ok=False,
            error=f"the reply is not a daemon's reply: {_worded(str(e))}",
        )


# What follows ``dishbot/<robot_id>/`` → the message on it. The schema's name is ``dishbot.<suffix>`` with
# ``/`` written ``_`` (``dishbot.input_joints``).
TOPICS: Final[Mapping[str, type[Message]]] = {
    "state": State,
    "joints": Joints,
    "input/joints": InputJoints,
    "gripper": Gripper,
    "detections": Detections,
    "input/observation": Observation,
    "plan": Plan,
    "events": Event,
    "log": Log,
    "input/force": Force,
    "input/holding": Holding,
    "input/grasp": Grasp,
    "input/joints_failed": ReadFailed,
    "input/gripper_failed": ReadFailed,
    "input/health_failed": ReadFailed,
    "input/device_event": DeviceEventInput,
    "input/motion": Motion,
    "input/grasp_failed": CallFailed,
    "input/observe_failed": CallFailed,
    "input/command": Command,
    "output/follow": Follow,
    "output/arm": ArmCommand,
    "output/gripper": GripperCommand,
}
HEADER_TOPIC: Final = "session/header"


# --- encoding and decoding ----------------------------------------------------------------------------------


def _fallback(value: object) -> object:
    """What JSON has no type for but a payload may hold: a numpy scalar (its Python value), a path (its
    text); anything else is refused (``TypeError``)."""
    item = getattr(value, "item", None)
    if callable(item) and getattr(value, "ndim", 0) == 0:
        plain = item()
        if isinstance(plain, bool | int | float | str):
            return plain
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


_ENCODER: Final = msgspec.json.Encoder(enc_hook=_fallback)


def encode(message: Message | Mapping[str, object]) -> bytes:
    """The message's bytes on Zenoh and in the recording: compact JSON in the declared (or the mapping's) key
    order, UTF-8. A number JSON cannot hold (NaN, infinity) is refused with ``ValueError``."""
    data = _ENCODER.encode(message)
    # msgspec writes a non-finite float as null: look for one only when the bytes have a null at all.
    if b"null" in data and not _finite(
        message if isinstance(message, Mapping) else msgspec.to_builtins(message)
    ):
        raise ValueError("Out of range float values are not JSON compliant")
    return data


def _finite(value: object) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, Mapping):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list | tuple):
        return all(_finite(v) for v in value)
    return True


M = TypeVar("M", bound=Message)

# What a producer hands ``publish``: the topic's declared message; on the open topics (``events`` from a
# driver or a fault file, ``log``) a mapping, which ``encode`` writes in its own key order.
Payload = Message | Mapping[str, object]


def as_message(payload: Payload, kind: type[M], *, name: str = "") -> M:
    """A published payload read as ``kind``: the message itself, or a mapping (or another message's fields)
    converted (``BadMessage`` when it is not one)."""
    if isinstance(payload, kind):
        return payload
    if isinstance(payload, Message):
        return convert(msgspec.to_builtins(payload), kind, name=name)
    return convert(payload, kind, name=name)


def plain(payload: Payload) -> Mapping[str, object]:
    """A payload as its JSON object (what the bytes hold): for readers of any topic's keys."""
    if isinstance(payload, Message):
        built: dict[str, object] = msgspec.to_builtins(payload, enc_hook=_fallback)
        return built
    return payload


def decode(data: bytes | str, kind: type[M], *, name: str = "") -> M:
    """``data`` (a payload's JSON) as a ``kind``; ``BadMessage`` with one line naming the message (``name``,
    else the type's) and what is wrong."""
    try:
        return msgspec.json.decode(data, type=kind)
    except msgspec.ValidationError as e:
        raise BadMessage(f"{name or kind.__name__}: {_worded(str(e))}") from None
    except msgspec.DecodeError as e:
        raise BadMessage(f"{name or kind.__name__}: not JSON: {e}") from None


def convert(value: Mapping[str, object], kind: type[M], *, name: str = "") -> M:
    """A decoded payload (a mapping, e.g. what a recording reader returns) as a ``kind``, like ``decode``."""
    try:
        return msgspec.convert(value, type=kind, strict=True)
    except msgspec.ValidationError as e:
        raise BadMessage(f"{name or kind.__name__}: {_worded(str(e))}") from None


def _worded(text: str) -> str:
    """msgspec's ``Expected `float`, got `str` - at `$.t``` as ``t: expected `float`, got `str```, and a
    missing field as ``slots[0].type: missing`` (the validator's wording)."""
    what, sep, where = text.partition(" - at `$")
    path = where.rstrip("`").lstrip(".") if sep else ""
    missing = re.fullmatch(r"Object missing required field `(.+)`", what)
    if missing is not None:
        return f"{path}.{missing[1]}: missing" if path else f"{missing[1]}: missing"
    said = what[:1].lower() + what[1:]
    return f"{path}: {said}" if path else said


def message_type(topic: str) -> type[Message] | None:
    """The message on ``topic`` (a full key, or what follows ``dishbot/<robot_id>/``); None for a topic
    dishbot does not describe."""
    if topic == HEADER_TOPIC:
        return SessionHeader
    return TOPICS.get(topic_suffix(topic))


def decode_topic(topic: str, data: bytes | str) -> Message:
    """A payload of ``topic`` as its declared message (``BadMessage`` when it is not one, or when nothing is
    declared for the topic)."""
    kind = message_type(topic)
    if kind is None:
        raise BadMessage(f"{topic}: no message is declared for this topic")
    return decode(data, kind, name=topic_suffix(topic))


def topic_suffix(topic: str) -> str:
    """What follows ``dishbot/<robot_id>/`` (the topic itself when it is not in that namespace)."""
    parts = topic.split("/", 2)
    return parts[2] if len(parts) == 3 and parts[0] == "dishbot" else topic


__all__ = [
    "EVENT_KINDS",
    "HEADER_TOPIC",
    "TOPICS",
    "UNSET",
    "BadMessage",
    "Message",
    "Payload",
    "UnsetType",
    "as_message",
    "convert",
    "decode",
    "decode_event",
    "decode_topic",
    "encode",
    "header_part",
    "message_type",
    "plain",
    "reply_of",
    "topic_suffix",
    "view",
]
