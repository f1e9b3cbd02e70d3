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
import re
import sys
from dataclasses import dataclass
from typing import Annotated, Any

import msgspec

from daemon.backend import SetupMug
from daemon.config import Config, PlannerCost, PlannerFitness, PlannerMethod, PlannerTimeLimit, Seed
from daemon.job import CommandRefused, Job, PlannerRequest, StartRequest
from daemon.security import FLEET_VERBS
from description import thesis
from validation import convert, show, within
from wire.messages import plain

VERBS = ("status", "start", "pause", "resume", "stop", "estop", "reset")
_MAX_MUGS = 64
# The deepest command is three levels (start -> mugs -> a mug); anything much deeper is not a command.
MAX_NESTING = 8
_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"?', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")


class BadCommand(ValueError):
    """The command's verb or payload is malformed; the message says which field and why."""


# The bodies, declared once and checked by the one validator (``validation``); the planner fields take the
# ranges and choices of ``[planner]`` in the config.

MugId = Annotated[
    str,
    msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}\Z", extra={"expected": "1-32 letters, digits, '_' or '-'"}),
]
CounterCoordinate = Annotated[float, within(-2.0, 2.0)]


@dataclass(frozen=True, slots=True)
class MugBody:
    """One counter mug of ``start``'s ``mugs``: its id, its configured type and where it stands."""

    id: MugId
    type: str  # one of the config's mug types, checked against the running config
    x_m: CounterCoordinate
    y_m: CounterCoordinate


@dataclass(frozen=True, slots=True)
class PlannerBody:
    """``start``'s ``planner``: the config's placement settings a job may override."""

    method: PlannerMethod | None = None
    cost: PlannerCost | None = None
    fitness: PlannerFitness | None = None
    time_limit_s: PlannerTimeLimit | None = None
    seed: Seed | None = None


@dataclass(frozen=True, slots=True)
class StartBody:
    """``start``: a dataset or the counter's mugs (simulation only), and planner overrides."""

    dataset: Annotated[int, within(1, max(thesis.DATASETS))] | None = None
    mugs: Annotated[list[MugBody], msgspec.Meta(min_length=1, max_length=_MAX_MUGS)] | None = None
    planner: PlannerBody | None = None


def parse(verb: str, payload: bytes, config: Config) -> StartRequest | None:
    """Validate one command; the ``StartRequest`` for ``start``, None for the other verbs."""
    if verb not in VERBS:
        raise BadCommand(f"unknown command {verb!r} (known: {', '.join(VERBS)})")
    body = _body(payload)
    if verb != "start":
        if body:
            raise BadCommand(f"{verb} takes no arguments, got {', '.join(repr(k) for k in sorted(body))}")
        return None
    if "dataset" in body and "mugs" in body:
        raise BadCommand("give either dataset or mugs, not both")
    start: StartBody = convert(body, StartBody, error=BadCommand, root="start")
    mugs = _mugs(start.mugs, config) if start.mugs is not None else None
    p = start.planner or PlannerBody()
    planner = PlannerRequest(
        method=p.method, cost=p.cost, fitness=p.fitness, time_limit_s=p.time_limit_s, seed=p.seed
    )
    return StartRequest(dataset=start.dataset, mugs=mugs, planner=planner)


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
    out = {**plain(job.status()), "summary": job.summary.to_json(), "allowed": allowed}
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


def _mugs(mugs: list[MugBody], config: Config) -> tuple[SetupMug, ...]:
    """The mugs' types are the config's, and no id is used twice."""
    types = [m.name for m in config.mug_types]
    for i, mug in enumerate(mugs):
        if mug.type not in types:
            raise BadCommand(
                f"mugs[{i}].type: {mug.type!r} is not a configured mug type ({', '.join(types)})"
            )
    ids = [m.id for m in mugs]
    duplicate = next((i for i in ids if ids.count(i) > 1), None)
    if duplicate is not None:
        raise BadCommand(f"mugs: id {duplicate!r} is used twice")
    return tuple(SetupMug(m.id, m.type, m.x_m, m.y_m) for m in mugs)


def _kind(value: object) -> str:
    return "an object" if isinstance(value, dict) else "null" if value is None else show(value)
