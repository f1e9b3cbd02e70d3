"""The JSON Schema of every topic the daemon records, written here rather than guessed from a first message.

A channel's schema has to describe every message the channel will ever carry: the first ``events`` message
is a transition, but the channel also carries faults (``reason``), placements (``mug_id``, ``x_m``) and the
drivers' device events. Each schema names the fields dishbot writes, with their types and units; fields a
later version adds are allowed (``additionalProperties``). The ``kind`` of an event and the ``state`` are
enumerations: a new event kind goes into ``EVENT_KINDS`` here (a test validates every message of a recorded
job against the schema stored with it).

Topics are matched by what follows ``dishbot/<robot_id>/``; a topic nobody described here (a test's, a
tool's) gets a schema that says only "a JSON object".
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Final

from statechart.chart import LEAVES

HEADER_TOPIC: Final = "session/header"
JSON_SCHEMA_DIALECT: Final = "https://json-schema.org/draft/2020-12/schema"

Schema = dict[str, object]

# Telemetry the daemon publishes and reads many times a second; idle recordings keep it at a lower rate.
TELEMETRY_TOPICS: Final = frozenset({"joints", "gripper", "input/joints", "input/force", "input/holding"})

# Every ``kind`` the job, the backends and the drivers put on ``events`` (README, "Zenoh key space").
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
    "counter_changed",
    "scene_set",
    "tray_collision",
    "warning",
    "servo_fault",
    "servo_recovered",
    "bus_lost",
    "bus_restored",
    "gripper_overload_recovered",
    "fsr_lost",
    "fsr_stale",
    "fsr_restored",
    "recording_failed",
    "recording_restored",
)


def _number(description: str) -> Schema:
    return {"type": "number", "description": description}


def _integer(description: str) -> Schema:
    return {"type": "integer", "description": description}


def _string(description: str) -> Schema:
    return {"type": "string", "description": description}


def _boolean(description: str) -> Schema:
    return {"type": "boolean", "description": description}


def _nullable(schema: Schema) -> Schema:
    out = dict(schema)
    out["type"] = [schema["type"], "null"]
    return out


def _array(items: Schema, description: str) -> Schema:
    return {"type": "array", "items": items, "description": description}


def _object(properties: Mapping[str, Schema], required: tuple[str, ...] = (), **extra: object) -> Schema:
    doc: Schema = {"type": "object", "properties": dict(properties), "additionalProperties": True}
    if required:
        doc["required"] = list(required)
    doc.update(extra)
    return doc


_WALL_T = _number("wall clock at publication, Unix seconds")
_DEVICE_T = _number("the driver's own clock (monotonic or simulated), seconds")

_JOINTS = _object(
    {
        "t": _WALL_T,
        "t_device": _DEVICE_T,
        "names": _array({"type": "string"}, "joint names, base to wrist"),
        "position_rad": _array({"type": "number"}, "joint angles, rad"),
        "velocity_rad_s": _array({"type": "number"}, "joint velocities, rad/s"),
        "load": _array({"type": "number"}, "servo load, fraction of full torque (signed)"),
    },
    ("t", "names", "position_rad"),
)

_DETECTION = _object(
    {
        "id": _string("the job's id of the mug (m1, m2, ...; empty before association)"),
        "type": _string("mug type from the catalogue"),
        "x_m": _number("mug axis, world x, m"),
        "y_m": _number("mug axis, world y, m"),
        "upside_down": _boolean("the mug stands on its brim"),
        "handle_yaw_rad": _number("direction of the handle about world z, rad"),
        "handle_seen": _boolean("the camera saw the handle (else its direction is a guess)"),
        "confidence": _number("detector confidence, 0-1"),
    },
    ("type", "x_m", "y_m"),
)

_OBSERVATION_PROPERTIES: dict[str, Schema] = {
    "t": _number("time of the depth frame (the observer's clock), s"),
    "mugs": _array(_DETECTION, "the mugs seen on the counter"),
    "meta": {"type": "object", "description": "what produced the observation (source, frame id)"},
}

_DEPTH_PREVIEW = _object(
    {
        "width": _integer("pixels across"),
        "height": _integer("pixels down"),
        "encoding": {"const": "uint16_mm_le_base64"},
        "data": _string("depth in mm, unsigned 16-bit little-endian, row-major, base64 (0 = no reading)"),
    },
    ("width", "height", "encoding", "data"),
)

_SLOT = _object(
    {
        "id": _string("mug id"),
        "type": _string("mug type"),
        "x_m": _number("mug axis in the slot, world x, m"),
        "y_m": _number("mug axis in the slot, world y, m"),
        "rotated": _boolean("footprint turned by 90 degrees"),
    },
    ("id", "type", "x_m", "y_m"),
)

_PLACED = _object(
    {
        "id": _string("mug id"),
        "type": _string("mug type"),
        "x_mm": _number("footprint corner on the tray, tray x, mm"),
        "y_mm": _number("footprint corner on the tray, tray y, mm"),
        "rotated": _boolean("footprint turned by 90 degrees"),
        "order": _integer("position in the placing order"),
        "brim_mm": _nullable(
            _array({"type": "number"}, "brim centre on the tray, [x, y], tray coordinates, mm")
        ),
        "handle_yaw_rad": _nullable(_number("where the arm leaves the handle, tray frame, rad (0 = +x)")),
    }
)

_EVENT_PROPERTIES: dict[str, Schema] = {
    "kind": {"type": "string", "enum": list(EVENT_KINDS), "description": "what happened"},
    "state": _string("the chart's state when it happened"),
    "t": _WALL_T,
    "mug_id": _string("the mug concerned (grasp_failed, mug_dropped, mug_placed, mug_given_up, ...)"),
    "reason": _string("why (fault, mug_given_up, motion_refused, mug_swapped)"),
    "trigger": _string("transition: the event that fired it"),
    "source": _string("transition: the state left"),
    "dest": _string("transition: the state entered"),
    "x_m": _number("mug_placed: the slot, world x, m; mug_found: where the mug was seen"),
    "y_m": _number("mug_placed: the slot, world y, m; mug_found: where the mug was seen"),
    "handle_yaw_rad": _number("mug_placed: where the handle lands, rad (when the camera saw it)"),
    "retry": _boolean("cycle_planned: a new cycle for a mug that was lost"),
    "duration_s": _number("cycle_planned: duration of the planned cycle, s"),
    "energy_j": _number("cycle_planned: energy of the planned cycle, J"),
    "came": _array({"type": "string"}, "counter_changed: mugs that appeared"),
    "went": _array({"type": "string"}, "counter_changed: mugs that disappeared"),
    "slot_for": _string("mug_swapped: the mug whose slot was handed over"),
    "message": _string("warning: what is wrong"),
    "scene": {"type": "object", "description": "scene_set: the new scene (mugs, tray, dataset)"},
    "device": _string("device events: which device (servo bus, fsr)"),
    "port": _string("device events: the serial port"),
    "servo_id": _integer("servo events: the servo's bus id"),
    "error": _string("device events: the driver's error"),
    "t_device": _DEVICE_T,
    "force_n": _number("mug_dropped (fsr), tray_collision: force, N"),
    "a": _string("tray_collision: first body"),
    "b": _string("tray_collision: second body"),
    "position_m": _array({"type": "number"}, "tray_collision: contact point, world frame, m"),
    "t_sim": _number("tray_collision: simulated time, s"),
    "event": _string("tray_collision: the collision's own name"),
    "path": _string("recording_failed, recording_restored: the recording file"),
    "dropped": _integer("recording_failed: messages the recording lost so far"),
}

_ERROR_PROPERTIES: Final[dict[str, Schema]] = {
    "error": _string("the driver's error when the call failed: its type, a colon, its message"),
    "error_class": _string("the error's type: its module and name (a replay raises the same again)"),
    "error_servo_id": _integer("the servo a ServoFault names"),
    "error_bits": _array({"type": "string"}, "the error bits a ServoFault names"),
    "error_port": _string("the port a BusLost names"),
}

_FAILED_PROPERTIES: Final[dict[str, Schema]] = {
    **_ERROR_PROPERTIES,
    "cancelled": _boolean("the call was cancelled (the job left the state)"),
    "t_start": _DEVICE_T,
    "t_end": _DEVICE_T,
}

# Where the job was when an input from outside it came (``daemon.backend.JobPosition``): a replay sends it
# again when its job is at the same place.
_POSITION_PROPERTIES: Final[dict[str, Schema]] = {
    "at_state": _string("the job's state when it came"),
    "at_transitions": _integer("transitions since the job's start (the start's own included) when it came"),
    "at_device_commands": _integer("device commands (moves, openings, closes, looks, stops) the job gave"),
}

_READ_FAILED: Final = _object({"t": _WALL_T, "t_read": _DEVICE_T, **_ERROR_PROPERTIES}, ("t_read", "error"))

_SCHEMAS: Final[dict[str, Schema]] = {
    "state": _object(
        {
            "state": {"type": "string", "enum": list(LEAVES), "description": "the chart's leaf state"},
            "mugs_total": _integer("mugs known: on the counter and on the tray"),
            "mugs_planned": _integer("mugs with a tray slot"),
            "mugs_placed": _integer("mugs on the tray"),
            "mugs_failed": _integer("mugs given up"),
            "current_mug": _nullable(_string("the mug being handled")),
            "transitions": _integer("transitions since the daemon started"),
            "t": _WALL_T,
        },
        ("state", "mugs_total", "mugs_placed", "t"),
    ),
    "joints": _JOINTS,
    "input/joints": _JOINTS,
    "gripper": _object(
        {
            "t": _WALL_T,
            "t_device": _DEVICE_T,
            "aperture_m": _number("distance between thumb and finger, m"),
            "load": _number("gripper servo load, fraction of full torque"),
            "force_n": _nullable(_number("FSR pad force, N")),
            "raw": _nullable(_integer("FSR ADC reading")),
            "seq": _nullable(_integer("FSR sample number")),
            "holding": _boolean("the debounced force says a mug is held"),
        },
        ("t", "aperture_m", "holding"),
    ),
    "detections": _object(
        {**_OBSERVATION_PROPERTIES, "depth_preview": _DEPTH_PREVIEW},
        ("t", "mugs"),
    ),
    "input/observation": _object(_OBSERVATION_PROPERTIES, ("t", "mugs")),
    "plan": _object(
        {
            "method": _string("placement method used"),
            "heuristic": _string("packing heuristic"),
            "sort": _nullable(_string("mug order heuristic")),
            "fitness": _string("fitness function"),
            "cost_function": _string("cost function"),
            "seed": _integer("random seed"),
            "wall_time_s": _number("planning time, s"),
            "placed": _array(_PLACED, "the mugs given a slot, tray coordinates"),
            "unplaced": _array({"type": "string"}, "mugs that do not fit"),
            "n": _integer("mugs placed"),
            "A": _number("tray area used, mm²"),
            "E": _number("energy estimate, J"),
            "s": _integer("sorting score"),
            "cost": _number("the cost minimised"),
            "optimal": _nullable(_boolean("proven optimal (null: no solver said)")),
            "upper_bound": _nullable(_integer("upper bound on the mugs that fit")),
            "gap": _nullable(_integer("upper bound minus mugs placed")),
            "status": _string("solver status"),
            "evaluations": _integer("layouts evaluated"),
            "notes": _array({"type": "string"}, "planner remarks"),
            "slots": _array(_SLOT, "the slots in placing order, world frame"),
            "t": _number("wall clock at publication, Unix seconds"),
            "t_plan_s": _number("the plan's time estimate: the cycles and the computation, s"),
        },
        ("slots",),
    ),
    "events": _object(_EVENT_PROPERTIES, ("kind",)),
    "log": _object(
        {
            "event": _string("the structlog event name"),
            "level": _string("the logging method: debug, info, warning, error, exception, critical"),
            "timestamp": _string("when it was logged, as the log renderer writes it"),
            "logger": _string("the logger's name"),
            "process": _string("'planning' for records relayed from the planning worker"),
            "mug_id": _string("the mug the record is about"),
            "state": _string("the chart state the record is about"),
            "error": _string("an error's text"),
            "reason": _string("why"),
            "exception": _string("the exception logged with the record: its type and message"),
            "traceback": _string("that exception's traceback, as Python prints it"),
            "t": _number("the session's clock when the daemon published the record, s"),
        },
        ("event", "level"),
    ),
    "input/force": _object(
        {
            "t": _DEVICE_T,
            "force_n": _number("FSR pad force, N"),
            "raw": _integer("FSR ADC reading"),
            "seq": _integer("FSR sample number"),
        },
        ("force_n",),
    ),
    "input/holding": _object({"holding": _boolean("the debounced force says a mug is held")}, ("holding",)),
    "input/grasp": _object(
        {
            "held": _boolean("the gripper's close says it holds the mug"),
            "force_n": _number("pad force when the close ended, N"),
            "aperture_m": _number("aperture when the close ended, m"),
            "reason": _string("why the close ended"),
            "force_threshold_n": _number("the force the close was asked to reach, N"),
            "min_aperture_m": _number("the aperture below which the close gives up, m"),
            "t_start": _DEVICE_T,
            "t_end": _DEVICE_T,
        },
        ("held",),
    ),
    "input/joints_failed": _READ_FAILED,
    "input/gripper_failed": _READ_FAILED,
    "input/health_failed": _READ_FAILED,
    "input/device_event": _object(
        {**_EVENT_PROPERTIES, **_POSITION_PROPERTIES, "t_read": _DEVICE_T},
        ("kind", "t_read"),
    ),
    "input/motion": _object(
        {
            "call": {"type": "string", "enum": ["plan_cycle", "plan_for_slot", "plan_move"]},
            "args_digest": _string("SHA-256 (first 32 hex digits) over the call's arguments (wire.motion)"),
            "result": {
                "type": "object",
                "description": "the plan: a cycle plan, {mug, plan} or a trajectory (float64 base64 arrays)",
            },
            "refused": _string("MotionRefused: why no motion exists"),
            "blockers": _array({"type": "string"}, "MotionRefused: the mugs that made it impossible"),
            **_ERROR_PROPERTIES,
        },
        ("call", "args_digest"),
    ),
    "input/grasp_failed": _object(_FAILED_PROPERTIES, ("t_start", "t_end")),
    "input/observe_failed": _object(_FAILED_PROPERTIES, ("t_start", "t_end")),
    "input/command": _object(
        {
            "t": _WALL_T,
            "verb": _string("the command's verb (cmd/<verb>); status queries are not kept"),
            "payload": _string("the command's JSON payload as received (UTF-8, undecodable bytes replaced)"),
            "many": _boolean("the query named robots by wildcard"),
            "reply": {"type": "object", "description": "the daemon's reply"},
            "t_device": _DEVICE_T,
            **_POSITION_PROPERTIES,
        },
        ("t", "verb", "payload"),
    ),
    "output/follow": _object(
        {
            "label": _string("what the trajectory is for (approach, lift, transit, ...)"),
            "points": _integer("trajectory points"),
            "duration_s": _number("the trajectory's planned duration, s"),
            "end_rad": _array({"type": "number"}, "the goal joint positions, rad"),
            "t_start": _DEVICE_T,
            "t_end": _DEVICE_T,
            **_FAILED_PROPERTIES,
        },
        ("label", "t_start", "t_end"),
    ),
    "output/arm": _object(
        {"action": _string("stop (hold here) or relax (torque off)"), "t_start": _DEVICE_T}, ("action",)
    ),
    "output/gripper": _object(
        {
            "action": _string("open or stop"),
            "aperture_m": _nullable(_number("the opening asked for, m (null: fully)")),
            "t_start": _DEVICE_T,
            "t_end": _DEVICE_T,
            **_FAILED_PROPERTIES,
        },
        ("action",),
    ),
}

_HEADER = _object(
    {
        "config": {"type": "object", "description": "the effective configuration (dishbot config show)"},
        "scene": {"type": "object", "description": "the scene as the file opened (tray, mugs, dataset)"},
        "job": {
            "type": ["object", "null"],
            "description": "what the job in this file ran: dataset or mugs, planner settings, seeds",
        },
        "file": {"type": "object", "description": "kind (job or idle), writer pid, the file before it"},
    },
    ("config", "scene"),
)


def topic_suffix(topic: str) -> str:
    """What follows ``dishbot/<robot_id>/`` (the topic itself when it is not in that namespace)."""
    parts = topic.split("/", 2)
    return parts[2] if len(parts) == 3 and parts[0] == "dishbot" else topic


def schema_name(topic: str) -> str:
    """The schema's name as recorded: ``dishbot.<suffix>`` for dishbot's topics, else the topic."""
    if topic == HEADER_TOPIC:
        return "dishbot.session_header"
    suffix = topic_suffix(topic)
    return f"dishbot.{suffix.replace('/', '_')}" if suffix in _SCHEMAS else topic


def schema_for(topic: str) -> Schema:
    """The JSON Schema of a recorded topic (a bare object schema for topics dishbot does not describe)."""
    body = _HEADER if topic == HEADER_TOPIC else _SCHEMAS.get(topic_suffix(topic), {"type": "object"})
    return {"$schema": JSON_SCHEMA_DIALECT, "title": schema_name(topic), **body}


def schema_bytes(topic: str) -> bytes:
    return json.dumps(schema_for(topic), separators=(",", ":"), ensure_ascii=False).encode()


def is_telemetry(topic: str) -> bool:
    """Whether a topic is high-rate telemetry (kept at a lower rate in idle recordings)."""
    return topic_suffix(topic) in TELEMETRY_TOPICS


def described_topics() -> tuple[str, ...]:
    """The topic suffixes this module has a schema for."""
    return tuple(_SCHEMAS)
