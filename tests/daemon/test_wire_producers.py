"""The daemon's producers build the declared messages (``wire.messages``) and write the very bytes they wrote
as mappings: the same keys, in the same order, with the same values. The mappings below are the producers'
code as it was before (golden shapes); each message is compared with them byte for byte, over generated
values, and the recorded backend's messages key by key, on every path (done, failed, cancelled)."""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import Callable, Coroutine, Mapping
from typing import Any, TypeVar

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from daemon.clock import SimulatedClock
from daemon.messages import (
    depth_preview,
    detections_message,
    failure_fields,
    gripper_message,
    joints_message,
    observation_input,
    plan_message,
)
from daemon.recorded import JobPosition, recorded
from drivers.errors import BusLost, DriverError, ServoFault
from drivers.interfaces import ForceReading, GripperState, JointState, JointTrajectory
from perception.interfaces import Detection, Observation
from planning.interfaces import MotionRefused
from planning.placement.planner import PlacedMug, PlanResult
from tests.fakes.job import make_backend, make_world
from wire.messages import Command, Message, OutOfReach, Payload, Slot, decode_topic, encode

T = TypeVar("T")

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
small = st.floats(-10, 10, allow_nan=False, allow_infinity=False)


def _old_detection(d: Detection, *, exact: bool) -> dict[str, object]:
    def r(v: float, digits: int) -> float:
        return v if exact else round(v, digits)

    return {
        "id": d.mug_id,
        "type": d.type,
        "x_m": r(d.x_m, 5),
        "y_m": r(d.y_m, 5),
        "upside_down": d.upside_down,
        "handle_yaw_rad": r(d.handle_yaw_rad, 5),
        "handle_seen": d.handle_seen,
        "confidence": r(d.confidence, 4),
    }


def _old_joints(js: JointState, *, t: float, exact: bool = False) -> dict[str, object]:
    def r(v: float, digits: int) -> float:
        return v if exact else round(v, digits)

    return {
        "t": t,
        "t_device": js.t,
        "names": list(js.names),
        "position_rad": [r(v, 6) for v in js.position_rad],
        "velocity_rad_s": [r(v, 6) for v in js.velocity_rad_s],
        "load": [r(v, 4) for v in js.load],
    }


def _old_observation(obs: Observation, *, t: float, exact: bool = False) -> dict[str, object]:
    mugs = [_old_detection(d, exact=exact) for d in obs.detections]
    return {"t": t, "t_device": obs.t, "mugs": mugs, "meta": dict(obs.meta)}


def _old_depth_preview(depth_m: np.ndarray) -> dict[str, object]:
    mm = np.nan_to_num(np.asarray(depth_m, dtype=np.float64) * 1000.0, nan=0.0, posinf=0.0, neginf=0.0)
    data = np.clip(np.rint(mm), 0, 65535).astype("<u2")
    return {
        "width": int(data.shape[1]),
        "height": int(data.shape[0]),
        "encoding": "uint16_mm_le_base64",
        "data": base64.b64encode(data.tobytes()).decode("ascii"),
    }


def _old_failure_fields(e: BaseException) -> dict[str, object]:
    out: dict[str, object] = {
        "error": f"{type(e).__name__}: {e}",
        "error_class": f"{type(e).__module__}.{type(e).__qualname__}",
    }
    for key in ("servo_id", "port"):
        value = getattr(e, key, None)
        if isinstance(value, str | int) and not isinstance(value, bool):
            out[f"error_{key}"] = value
    bits = getattr(e, "bits", None)
    if isinstance(bits, tuple) and all(isinstance(b, str) for b in bits):
        out["error_bits"] = list(bits)
    return out


def _same(message: Payload, old: Mapping[str, object], topic: str) -> None:
    """The message's bytes are the old mapping's, and they decode as the topic's declared message."""
    data = encode(message)
    assert data == encode(old)
    assert list(json.loads(data)) == list(old)  # key by key, in order
    decode_topic(topic, data)


joint_states = st.integers(1, 6).flatmap(
    lambda n: st.builds(
        JointState,
        t=finite,
        names=st.just(tuple(f"j{i}" for i in range(n))),
        position_rad=st.tuples(*[small] * n),
        velocity_rad_s=st.tuples(*[small] * n),
        load=st.tuples(*[st.floats(-1, 1)] * n),
    )
)
detections = st.builds(
    Detection,
    type=st.sampled_from(["small", "big"]),
    x_m=small,
    y_m=small,
    upside_down=st.booleans(),
    handle_yaw_rad=small,
    confidence=st.floats(0, 1),
    mug_id=st.sampled_from(["", "m1", "m12"]),
    handle_seen=st.booleans(),
)
SHAPES = hnp.array_shapes(min_dims=2, max_dims=2, max_side=6)
observations = st.builds(
    Observation,
    t=finite,
    detections=st.lists(detections, max_size=4).map(tuple),
    meta=st.sampled_from([{}, {"source": "camera", "frame": 3}]),
)


@settings(max_examples=60, deadline=None)
@given(js=joint_states, t=finite)
def test_joints_are_written_as_before(js: JointState, t: float) -> None:
    _same(joints_message(js, t=t), _old_joints(js, t=t), "joints")


@settings(max_examples=60, deadline=None)
@given(
    gs=st.builds(GripperState, t=finite, aperture_m=st.floats(0, 0.1), load=st.floats(-1, 1)),
    reading=st.none()
    | st.builds(
        ForceReading, t=finite, force_n=st.floats(0, 50), raw=st.integers(0, 4095), seq=st.integers(0, 10**6)
    ),
    holding=st.booleans(),
    t=finite,
)
def test_gripper_samples_are_written_as_before(
    gs: GripperState, reading: ForceReading | None, holding: bool, t: float
) -> None:
    old = {
        "t": t,
        "t_device": gs.t,
        "aperture_m": round(gs.aperture_m, 5),
        "load": round(gs.load, 4),
        "force_n": None if reading is None else round(reading.force_n, 4),
        "raw": None if reading is None else reading.raw,
        "seq": None if reading is None else reading.seq,
        "holding": holding,
    }
    _same(gripper_message(gs, reading, holding=holding, t=t), old, "gripper")


@settings(max_examples=40, deadline=None)
@given(
    obs=observations,
    t=finite,
    depth=st.none()
    | hnp.arrays(
        np.float32, hnp.array_shapes(min_dims=2, max_dims=2, max_side=6), elements=st.floats(-1, 80, width=32)
    ),
    ends=st.tuples(finite, finite),
)
def test_detections_and_observations_are_written_as_before(
    obs: Observation, t: float, depth: np.ndarray | None, ends: tuple[float, float]
) -> None:
    old = _old_observation(obs, t=t)
    preview = None
    if depth is not None:
        preview = depth_preview(depth)
        old["depth_preview"] = _old_depth_preview(depth)
    _same(detections_message(obs, t=t, depth_preview=preview), old, "detections")
    recorded_old = {**_old_observation(obs, t=t, exact=True), "t_start": ends[0], "t_end": ends[1]}
    _same(observation_input(obs, t=t, t_start=ends[0], t_end=ends[1]), recorded_old, "input/observation")


def test_a_depth_preview_with_no_readings_is_written_as_before() -> None:
    depth = np.array([[np.nan, np.inf], [-np.inf, 70.0]], np.float32)
    assert encode(depth_preview(depth)) == encode(_old_depth_preview(depth))


@settings(max_examples=40, deadline=None)
@given(
    placed=st.lists(
        st.builds(
            PlacedMug,
            id=st.sampled_from(["m1", "m2"]),
            type=st.sampled_from(["small", "big"]),
            x_mm=st.integers(0, 400),
            y_mm=st.integers(0, 400),
            rotated=st.booleans(),
            order=st.integers(1, 30),
            brim_mm=st.none() | st.tuples(finite, finite),
            handle_yaw_rad=st.none() | small,
        ),
        max_size=3,
    ),
    numbers=st.tuples(finite, finite, finite, finite, finite),
    optimal=st.none() | st.booleans(),
    upper_bound=st.none() | st.integers(0, 30),
    sort=st.none() | st.just("area"),
    t=finite,
)
def test_plans_are_written_as_before(
    placed: list[PlacedMug],
    numbers: tuple[float, float, float, float, float],
    optimal: bool | None,
    upper_bound: int | None,
    sort: str | None,
    t: float,
) -> None:
    wall, area, energy, t_s, cost = numbers
    result = PlanResult(
        method="bh",
        heuristic="bl",
        sort=sort,
        fitness="count",
        cost_function="energy",
        seed=3,
        wall_time_s=abs(wall),
        placed=tuple(placed),
        unplaced=("m9",),
        n=len(placed),
        A_mm2=area,
        E_j=energy,
        t_s=t_s,
        s=2,
        cost=cost,
        optimal=optimal,
        upper_bound=upper_bound,
        status="optimal",
        evaluations=12,
        notes=("a note",),
    )
    out_of_reach = [OutOfReach(id="m9", reason="too far")]
    slots = [Slot(id="m1", type="small", x_m=0.31234, y_m=-0.1, rotated=False)]
    old = result.to_json()  # the producer's code before: the planner's JSON, then the job's fields
    old["out_of_reach"] = [{"id": "m9", "reason": "too far"}]
    old["slots"] = [{"id": "m1", "type": "small", "x_m": 0.31234, "y_m": -0.1, "rotated": False}]
    old["t_plan_s"] = old["t"]
    old["t"] = t
    _same(plan_message(result, out_of_reach=out_of_reach, slots=slots, t=t), old, "plan")


@pytest.mark.parametrize(
    "error",
    [
        DriverError("no answer"),
        ServoFault("servo 3 reports overload", servo_id=3, bits=("overload", "voltage")),
        ServoFault("servo 2 is silent", servo_id=2),
        BusLost("servo bus /dev/x is gone", port="/dev/x"),
        RuntimeError("other"),
    ],
)
def test_a_failed_call_is_written_as_before(error: BaseException) -> None:
    assert list(failure_fields(error).items()) == list(_old_failure_fields(error).items())


@settings(max_examples=30, deadline=None)
@given(
    t=finite,
    t_device=finite,
    many=st.booleans(),
    at=st.tuples(st.sampled_from(["idle", "pick.grasp"]), st.integers(0, 99), st.integers(0, 99)),
)
def test_a_recorded_command_is_written_as_before(
    t: float, t_device: float, many: bool, at: tuple[str, int, int]
) -> None:
    reply = {"ok": True, "state": "idle"}
    old = {
        "t": t,
        "t_device": t_device,
        "verb": "start",
        "payload": '{"dataset":1}',
        "many": many,
        "reply": reply,
        "at_state": at[0],
        "at_transitions": at[1],
        "at_device_commands": at[2],
    }
    new = Command(
        t=t,
        t_device=t_device,
        verb="start",
        payload='{"dataset":1}',
        many=many,
        reply=reply,
        at_state=at[0],
        at_transitions=at[1],
        at_device_commands=at[2],
    )
    _same(new, old, "input/command")


# --- the recorded backend, key by key ---------------------------------------------------------------------

# The keys each recorded message had, in order, as the wrappers wrote them before they built the structs
# (and a joint read's ``reader``, added since: issue 20).
FAILED = ["error", "error_class"]
GOLDEN: dict[str, list[str]] = {
    "input/joints": ["t", "t_device", "names", "position_rad", "velocity_rad_s", "load", "t_read", "reader"],
    "output/follow": ["label", "points", "duration_s", "end_rad", "t_start", "t_end"],
    "output/arm": ["action", "t_start"],
    "output/gripper open": ["action", "aperture_m", "t_start", "t_end"],
    "output/gripper stop": ["action", "t_start"],
    "input/grasp": [
        "held",
        "force_n",
        "aperture_m",
        "reason",
        "force_threshold_n",
        "min_aperture_m",
        "t_start",
        "t_end",
    ],
    "input/force": ["t", "t_device", "t_read", "force_n", "raw", "seq"],
    "input/holding": ["holding", "t_read"],
    "input/observation": ["t", "t_device", "mugs", "meta", "t_start", "t_end"],
    "input/motion": ["call", "args_digest", "result"],
    "input/motion refused": ["call", "args_digest", "refused", "blockers"],
    "input/motion failed": ["call", "args_digest", *FAILED],
    "input/joints_failed": ["t", "t_read", *FAILED, "error_servo_id", "error_bits", "reader"],
    "input/gripper_failed": ["t", "t_read", *FAILED, "error_port"],
    "output/follow cancelled": ["label", "points", "duration_s", "end_rad", "t_start", "t_end", "cancelled"],
    "output/gripper failed": ["action", "aperture_m", "t_start", "t_end", *FAILED],
    "input/grasp_failed": ["force_threshold_n", "min_aperture_m", "t_start", "t_end", *FAILED],
    "input/observe_failed": ["t", "t_start", "t_end", "cancelled"],
}


def _run(clock: SimulatedClock, work: Callable[[], Coroutine[Any, Any, T]]) -> T:
    return clock.run(work())


def test_the_recorded_backend_writes_every_message_as_before() -> None:
    clock = SimulatedClock()
    world = make_world(2)
    inner = make_backend(world, refuse=("true1",), clock=clock)
    sunk: list[tuple[str, Payload]] = []
    backend = recorded(inner, lambda topic, payload: sunk.append((topic, payload)), JobPosition())
    seen: dict[str, list[str]] = {}

    def take(name: str) -> dict[str, Any]:
        topic, payload = sunk.pop(0)
        assert name.split(" ")[0] == topic
        assert isinstance(payload, Message)  # the declared struct, built by the wrapper
        data = encode(payload)
        decode_topic(topic, data)
        doc: dict[str, Any] = json.loads(data)
        seen[name] = list(doc)
        return doc

    async def done_paths() -> None:
        js = await backend.arm.read_joints()
        assert take("input/joints")["position_rad"] == list(js.position_rad)  # unrounded
        line = JointTrajectory(
            js.names, np.array([0.0, 0.5]), np.array([js.position_rad, js.position_rad]), "lift"
        )
        await backend.arm.follow(line)
        assert take("output/follow")["label"] == "lift"
        await backend.arm.stop()
        assert take("output/arm")["action"] == "stop"
        await backend.gripper.open(0.05)
        take("output/gripper open")
        await backend.gripper.stop()
        take("output/gripper stop")
        await backend.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.01)
        take("input/grasp")
        if backend.force.latest() is not None:
            take("input/force")
        backend.force.holding()
        take("input/holding")
        await backend.observer.observe()
        assert len(take("input/observation")["mugs"]) == 2
        backend.motion.plan_move(js.position_rad, js.position_rad, label="transit")
        take("input/motion")

    _run(clock, done_paths)

    # Failures: each wrapped call raises, as a driver does.
    async def raising(*args: object, **kwargs: object) -> Any:
        raise failures.pop(0)

    failures: list[BaseException] = [
        ServoFault("servo 3 reports overload", servo_id=3, bits=("overload",)),
        BusLost("gripper bus gone", port="/dev/ttyUSB0"),
        DriverError("gripper stalled"),
        DriverError("no close"),
    ]
    inner.arm.read_joints = raising  # type: ignore[method-assign]
    inner.gripper.read = raising  # type: ignore[method-assign]
    inner.gripper.open = raising  # type: ignore[method-assign]
    inner.gripper.close_on_mug = raising  # type: ignore[method-assign]

    async def failed_paths() -> None:
        with pytest.raises(ServoFault):
            await backend.arm.read_joints()
        take("input/joints_failed")
        with pytest.raises(BusLost):
            await backend.gripper.read()
        take("input/gripper_failed")
        with pytest.raises(DriverError):
            await backend.gripper.open(None)
        take("output/gripper failed")
        with pytest.raises(DriverError):
            await backend.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.01)
        take("input/grasp_failed")

    _run(clock, failed_paths)

    async def never(*args: object, **kwargs: object) -> Any:
        await asyncio.Event().wait()

    inner.arm.follow = never  # type: ignore[method-assign]
    inner.observer.observe = never  # type: ignore[method-assign]

    async def cancelled_paths() -> None:
        line = JointTrajectory(("j1",), np.array([0.0]), np.zeros((1, 1)), "approach")
        for call in (backend.arm.follow(line), backend.observer.observe()):
            task = asyncio.ensure_future(call)
            await asyncio.sleep(0)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
        take("output/follow cancelled")
        take("input/observe_failed")

    _run(clock, cancelled_paths)

    def refused(*args: object, **kwargs: object) -> Any:
        raise MotionRefused("blocked", blockers={"m2", "m1"})

    def broken(*args: object, **kwargs: object) -> Any:
        raise RuntimeError("planner crashed")

    for stand_in, name in ((refused, "input/motion refused"), (broken, "input/motion failed")):
        inner.motion.plan_move = stand_in  # type: ignore[method-assign]
        with pytest.raises((MotionRefused, RuntimeError)):
            backend.motion.plan_move((0.0,), (0.0,), label="transit")
        doc = take(name)
        if name == "input/motion refused":
            assert doc["blockers"] == ["m1", "m2"]

    assert not sunk
    assert seen == GOLDEN
