"""The kinematic cell (placeholder simulation) and its truth detector, on a simulated clock."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Coroutine
from typing import Any, TypeVar

import numpy as np
import pytest

from daemon.clock import SimulatedClock
from drivers.errors import BusLost, LimitViolation
from drivers.interfaces import JointTrajectory
from perception.interfaces import Detection
from planning.arm import ArmModel
from sim.kinematic import KinematicCell, MugGeometry, SimMug, open_kinematic_cell
from sim.truth import TruthObserver

T = TypeVar("T")
GEOMETRY = {"big": MugGeometry(0.091, 0.106), "small": MugGeometry(0.074, 0.080)}
Q_LOW = np.array([0.0, -1.0, 1.5, 0.0, 0.0])  # grasp point about 4 cm above the counter
TRAY_ORIGIN = (0.30, -0.60)  # clear of the mugs these tests grasp near y = 0


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _cell(arm: ArmModel, mugs: list[SimMug], *, q0: np.ndarray = Q_LOW) -> KinematicCell:
    return open_kinematic_cell(
        mugs,
        GEOMETRY,
        tray_origin_m=TRAY_ORIGIN,
        tray_size_m=(0.332, 0.374),
        clock=SimulatedClock(),
        joint_speed_rad_s=1.0,
        holding_threshold_n=1.0,
        arm=arm,
        q0=q0,
    )


def _mug_between_pads(arm: ArmModel, q: np.ndarray, kind: str = "big") -> SimMug:
    p, r = arm.fk(q)
    axis = p + r[:, 1] * (GEOMETRY[kind].diameter_m / 2 - arm.gripper.thumb_width_m)
    return SimMug("a", kind, float(axis[0]), float(axis[1]))


def _move(names: tuple[str, ...], a: np.ndarray, b: np.ndarray, seconds: float) -> JointTrajectory:
    s = np.linspace(0.0, 1.0, 11)
    return JointTrajectory(names, s * seconds, a + np.outer(s, b - a), label="test")


def _run(cell: KinematicCell, main: Coroutine[Any, Any, T]) -> T:
    """Run ``main`` on the cell's clock."""
    clock = cell.world.clock
    assert isinstance(clock, SimulatedClock)
    return clock.run(main)


def test_the_arm_is_slowed_to_its_joint_speed_and_ends_at_the_goal(arm: ArmModel) -> None:
    cell = _cell(arm, [])
    goal = Q_LOW + np.array([0.5, 0.0, 0.0, 0.0, 0.0])

    async def go() -> float:
        t0 = cell.world.clock.monotonic()
        await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, goal, 0.05))
        return cell.world.clock.monotonic() - t0

    took = _run(cell, go())
    assert took == pytest.approx(0.5, abs=0.011)  # 0.5 rad at 1 rad/s (in 10 ms ticks), not the 0.05 s asked
    assert np.allclose(cell.world.q, goal)


def test_a_cancelled_move_leaves_the_arm_part_way(arm: ArmModel) -> None:
    cell = _cell(arm, [])
    goal = Q_LOW + np.array([1.0, 0.0, 0.0, 0.0, 0.0])

    async def go() -> None:
        task = asyncio.create_task(cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, goal, 1.0)))
        await cell.world.clock.sleep(0.25)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    _run(cell, go())
    assert cell.world.q[0] == pytest.approx(0.25, abs=0.011)  # a quarter of the way, at 1 rad/s


def test_a_trajectory_outside_the_joint_limits_is_refused_before_moving(arm: ArmModel) -> None:
    cell = _cell(arm, [])
    bad = Q_LOW.copy()
    bad[1] = 1.0
    expected = (
        r"^trajectory 'test' leaves the joint limits: "
        r"shoulder_lift=0\.4000 rad is outside \[-2\.0000, 0\.3000\]$"  # the first sample out of range
    )
    with pytest.raises(LimitViolation, match=expected):
        _run(cell, cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, bad, 1.0)))
    assert np.allclose(cell.world.q, Q_LOW)


def test_closing_on_a_mug_raises_the_pad_force_and_the_mug_follows_the_gripper(arm: ArmModel) -> None:
    mug = _mug_between_pads(arm, Q_LOW)
    cell = _cell(arm, [mug])

    async def go() -> None:
        result = await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        assert result.held
        assert result.force_n >= 2.0
        assert cell.force.holding()
        reading = cell.force.latest()
        assert reading is not None
        assert reading.force_n == pytest.approx(result.force_n)
        lifted = Q_LOW + np.array([0.3, -0.2, 0.0, 0.0, 0.0])
        await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, lifted, 1.0))

    _run(cell, go())
    moved = cell.world.mugs["a"]
    assert moved.where == "gripper"
    assert math.hypot(moved.x_m - mug.x_m, moved.y_m - mug.y_m) > 0.05


def test_closing_on_nothing_does_not_hold(arm: ArmModel) -> None:
    cell = _cell(arm, [SimMug("far", "big", -0.3, 0.4)])
    result = _run(cell, cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02))
    assert (result.held, result.reason, result.aperture_m) == (False, "closed on nothing", 0.02)
    assert not cell.force.holding()


def test_a_slipping_grasp_fails_and_pushes_the_mug_away(arm: ArmModel) -> None:
    mug = _mug_between_pads(arm, Q_LOW)
    cell = _cell(arm, [mug])
    cell.world.slip_next_grasp()
    result = _run(cell, cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02))
    assert not result.held
    after = cell.world.mugs["a"]
    assert math.hypot(after.x_m - mug.x_m, after.y_m - mug.y_m) == pytest.approx(0.04)
    assert after.where == "counter"


def test_a_dropped_mug_stops_the_force_and_lands_where_it_was(arm: ArmModel) -> None:
    cell = _cell(arm, [_mug_between_pads(arm, Q_LOW)])
    _run(cell, cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02))
    assert cell.world.drop_held_mug() == "a"
    assert not cell.force.holding()
    assert cell.world.mugs["a"].where == "counter"


def test_a_mug_released_over_the_tray_lands_on_the_tray(arm: ArmModel) -> None:
    cell = _cell(arm, [_mug_between_pads(arm, Q_LOW)])

    async def go() -> None:
        await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        cell.world.tray_origin_m = (cell.world.mugs["a"].x_m - 0.1, cell.world.mugs["a"].y_m - 0.1)
        await cell.gripper.open()

    _run(cell, go())
    assert cell.world.mugs["a"].where == "tray"
    assert cell.world.held is None


def test_a_partial_opening_lets_go_and_stops_short_of_fully_open(arm: ArmModel) -> None:
    cell = _cell(arm, [_mug_between_pads(arm, Q_LOW)])

    async def go() -> tuple[float, float]:
        held = await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        await cell.gripper.open(held.aperture_m + 0.006)
        partly = (await cell.gripper.read()).aperture_m
        await cell.gripper.open(0.01)  # narrower than it is: never closes
        return held.aperture_m, partly

    grasped, partly = _run(cell, go())
    assert cell.world.held is None
    assert partly == pytest.approx(grasped + 0.006, abs=1e-6)
    assert cell.world.aperture_m == pytest.approx(partly, abs=1e-6)


def test_a_lost_bus_fails_every_device_call(arm: ArmModel) -> None:
    cell = _cell(arm, [])
    cell.world.lose_bus("/dev/ttyUSB0")
    with pytest.raises(BusLost, match=r"^simulated bus on /dev/ttyUSB0 is gone; reconnect and reset$"):
        _run(cell, cell.arm.read_joints())


def test_the_truth_detector_adds_seeded_noise_and_no_ids() -> None:
    truth = [
        Detection("big", 0.3, 0.4, False, 0.0, 1.0, "secret"),
        Detection("small", 0.1, 0.45, False, 0.0, 1.0),
    ]

    def look(seed: int) -> tuple[Detection, ...]:
        clock = SimulatedClock()
        observer = TruthObserver(lambda: truth, clock=clock, noise_m=0.002, seed=seed)
        return clock.run(observer.observe()).detections

    first, again, other = look(1), look(1), look(2)
    assert first == again
    assert first != other
    assert [d.mug_id for d in first] == ["", ""]
    assert all(
        abs(d.x_m - t.x_m) < 0.01 and abs(d.y_m - t.y_m) < 0.01 for d, t in zip(first, truth, strict=True)
    )
    assert all(0.5 <= d.confidence <= 1.0 for d in first)


def test_a_depth_preview_is_published_as_16_bit_millimetres() -> None:
    import base64

    from daemon.backend import depth_preview_payload

    depth = np.array([[0.0, 1.25], [np.nan, 70.0]], dtype=np.float32)
    payload = depth_preview_payload(depth)
    assert (payload["width"], payload["height"], payload["encoding"]) == (2, 2, "uint16_mm_le_base64")
    values = np.frombuffer(base64.b64decode(str(payload["data"])), dtype="<u2").reshape(2, 2)
    assert values.tolist() == [[0, 1250], [0, 65535]]
