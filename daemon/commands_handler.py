"""Commands from the network: parse and validate a ``cmd/<verb>`` query, hand it to the job, build the reply.

A command is refused (``{"ok": false, "error": ...}``) and changes nothing when its verb is unknown, its
payload is not a JSON object, a field is unknown, has the wrong type or is out of range, or the verb is not
allowed in the current state. The size limit is enforced before the payload is decoded (in
``daemon.zenoh_session``), and so is the nesting limit (here): a payload nested deeper than any command
needs is refused before the JSON parser recurses into it.

A command addressed to many robots at once (``dishbot/*/cmd/<verb>``) is answered only for ``status`` and
``estop``: looking at every robot, and stopping every robot, are safe to do in one go; starting, pausing,
resuming, stopping or resetting robots nobody named is not.
"""

from __future__ import annotations

import json
import math
import re
import sys
from collections.abc import Mapping
from typing import Any

from daemon.backend import CounterMug
from daemon.config import PLANNER_COSTS, PLANNER_FITNESS, Config
from daemon.job import CommandRefused, Job, PlannerRequest, StartRequest
from daemon.security import FLEET_VERBS
from description import thesis
from planning.placement import METHODS

VERBS = ("status", "start", "pause", "resume", "stop", "estop", "reset")
_ID = re.compile(r"^[A-Za-z0-9_-]{1,32}$")
_MAX_MUGS = 64
_LONGEST_SHOWN = 20  # digits of an integer quoted in an error; a longer one is named by its length
# The deepest command is three levels (start -> mugs -> a mug); anything much deeper is not a command.
MAX_NESTING = 8
_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"?', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")


class BadCommand(ValueError):
    """The command's verb or payload is malformed; the message says which field and why."""


def parse(verb: str, payload: bytes, config: Config) -> StartRequest | None:
    """Validate one command; the ``StartRequest`` for ``start``, None for the other verbs."""
    if verb not in VERBS:
        raise BadCommand(f"unknown command {verb!r} (known: {', '.join(VERBS)})")
    body = _body(payload)
    if verb != "start":
        if body:
            raise BadCommand(f"{verb} takes no arguments, got {', '.join(repr(k) for k in sorted(body))}")
        return None
    _only(body, ("dataset", "mugs", "planner"), "start")
    if "dataset" in body and "mugs" in body:
        raise BadCommand("give either dataset or mugs, not both")
    dataset = None
    if "dataset" in body:
        dataset = _integer(body["dataset"], "dataset", 1, max(thesis.DATASETS))
    mugs = _mugs(body["mugs"], config) if "mugs" in body else None
    planner = _planner(body["planner"]) if "planner" in body else PlannerRequest()
    return StartRequest(dataset=dataset, mugs=mugs, planner=planner)


async def handle(job: Job, verb: str, payload: bytes, many: bool = False) -> dict[str, object]:
    """The reply to one command; ``many`` when the query named robots by wildcard."""
    try:
        if many and verb in VERBS and verb not in FLEET_VERBS:
            raise BadCommand(
                f"{verb} addressed to many robots is refused: name one robot "
                f"(only {' and '.join(FLEET_VERBS)} may go to every robot at once)"
            )
        request = parse(verb, payload, job.config)
        if verb == "status":
            return {"ok": True, **status(job)}
        result = await job.command(verb, request)
    except (BadCommand, CommandRefused) as e:
        return {"ok": False, "error": str(e)}
    return {"ok": True, **result}


def status(job: Job) -> dict[str, object]:
    """``status``: the state payload, the job's summary, the commands allowed now and the recording's
    health (``{"ok": false, "error": ...}`` once the disk failed)."""
    allowed = [v for v in VERBS if v == "status" or job.chart.can(v)]
    out = {**job.status(), "summary": job.summary.to_json(), "allowed": allowed}
    recording = job.recording()
    if recording is not None:
        out["recording"] = recording
    return out


def _body(payload: bytes) -> dict[str, Any]:
    if not payload.strip():
        return {}
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as e:
        raise BadCommand(f"payload is not UTF-8 text: {e.reason} at byte {e.start}") from e
    if nested_deeper_than(text, MAX_NESTING):
        raise BadCommand(f"command payload nested deeper than {MAX_NESTING} levels")
    try:
        body = json.loads(text)
    except RecursionError as e:  # not reached after the check above; a parser change must not crash
        raise BadCommand(f"command payload nested deeper than {MAX_NESTING} levels") from e
    except json.JSONDecodeError as e:
        raise BadCommand(f"payload is not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from e
    except ValueError as e:  # an integer longer than Python converts (only with a raised size limit)
        raise BadCommand(
            f"payload has an integer of more than {sys.get_int_max_str_digits()} digits; no field takes one"
        ) from e
    if not isinstance(body, dict):
        raise BadCommand(f"payload must be a JSON object, got {_kind(body)}")
    return body


def nested_deeper_than(text: str, levels: int) -> bool:
    """Whether the arrays and objects of a JSON text nest deeper than ``levels`` (brackets inside strings do
    not count), found without parsing it: the json module recurses once per level and gives up with
    ``RecursionError``."""
    depth = 0
    for c in _NOT_BRACKET.sub("", _STRING.sub("", text)):
        depth += 1 if c in "[{" else -1
        if depth > levels:
            return True
    return False


def _mugs(value: object, config: Config) -> tuple[CounterMug, ...]:
    if not isinstance(value, list):
        raise BadCommand(f"mugs: expected a list of mugs, got {_kind(value)}")
    if not 1 <= len(value) <= _MAX_MUGS:
        raise BadCommand(f"mugs: expected 1-{_MAX_MUGS} mugs, got {len(value)}")
    types = [m.name for m in config.mug_types]
    out = []
    for i, item in enumerate(value):
        where = f"mugs[{i}]"
        if not isinstance(item, dict):
            raise BadCommand(f"{where}: expected an object, got {_kind(item)}")
        _only(item, ("id", "type", "x_m", "y_m"), where)
        for field in ("id", "type", "x_m", "y_m"):
            if field not in item:
                raise BadCommand(f"{where}.{field}: missing")
        mug_id = item["id"]
        if not isinstance(mug_id, str) or not _ID.match(mug_id):
            raise BadCommand(f"{where}.id: expected 1-32 letters, digits, '_' or '-', got {mug_id!r}")
        if item["type"] not in types:
            raise BadCommand(
                f"{where}.type: {item['type']!r} is not a configured mug type ({', '.join(types)})"
            )
        x = _number(item["x_m"], f"{where}.x_m", -2.0, 2.0)
        y = _number(item["y_m"], f"{where}.y_m", -2.0, 2.0)
        out.append(CounterMug(mug_id, item["type"], x, y))
    ids = [m.mug_id for m in out]
    duplicate = next((i for i in ids if ids.count(i) > 1), None)
    if duplicate is not None:
        raise BadCommand(f"mugs: id {duplicate!r} is used twice")
    return tuple(out)


def _planner(value: object) -> PlannerRequest:
    if not isinstance(value, dict):
        raise BadCommand(f"planner: expected an object, got {_kind(value)}")
    _only(value, ("method", "cost", "fitness", "time_limit_s", "seed"), "planner")
    return PlannerRequest(
        method=_choice(value, "method", METHODS),
        cost=_choice(value, "cost", PLANNER_COSTS),
        fitness=_choice(value, "fitness", PLANNER_FITNESS),
        time_limit_s=(
            _number(value["time_limit_s"], "planner.time_limit_s", 0.01, 600.0)
            if "time_limit_s" in value
            else None
        ),
        seed=_integer(value["seed"], "planner.seed", 0, 2**31 - 1) if "seed" in value else None,
    )


def _only(body: Mapping[str, object], allowed: tuple[str, ...], where: str) -> None:
    for name in body:
        if name not in allowed:
            raise BadCommand(f"{where}: unknown field {name!r} (known: {', '.join(allowed)})")


def _choice(body: Mapping[str, object], name: str, allowed: tuple[str, ...]) -> str | None:
    if name not in body:
        return None
    value = body[name]
    if value not in allowed:
        raise BadCommand(f"planner.{name}: {value!r} is not one of {', '.join(allowed)}")
    return str(value)


def _integer(value: object, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadCommand(f"{name}: expected an integer {lo}-{hi}, got {_kind(value)}")
    if not lo <= value <= hi:
        raise BadCommand(f"{name}: {_kind(value)} is out of range {lo}-{hi}")
    return value


def _number(value: object, name: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BadCommand(f"{name}: expected a number in [{lo:g}, {hi:g}], got {_kind(value)}")
    # Compared as given: an integer too large for a float is out of range, not an OverflowError.
    if (isinstance(value, float) and not math.isfinite(value)) or not lo <= value <= hi:
        raise BadCommand(f"{name}: {_kind(value)} is out of range [{lo:g}, {hi:g}]")
    return float(value)


def _kind(value: object) -> str:
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "a list"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int) and abs(value) >= 10**_LONGEST_SHOWN:
        return f"an integer of {len(str(abs(value)))} digits"
    return repr(value)
