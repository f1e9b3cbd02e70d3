"""The kinematic cell on a simulated clock: the real drivers over the byte-level servo chain and FSR
simulators, moving a world without dynamics; its camera and truth detector behind the observer's frame
checks."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable
from typing import TypeVar

import numpy as np
import pytest

from daemon.clock import SimulatedClock
from description.thesis import MUG_TYPES
from drivers.errors import BusLost, LimitViolation, ServoFault
from drivers.interfaces import JointTrajectory
from perception.errors import CameraFault
from perception.interfaces import Detection
from planning.arm import ArmModel
from sim.kinematic import KinematicCell, MugGeometry, SimMug, start_kinematic_cell
from sim.truth import TruthCamera, TruthDetector

T = TypeVar("T")
GEOMETRY = {"big": MugGeometry(0.091, 0.106), "small": MugGeometry(0.074, 0.080)}
Q_LOW = np.array([0.0, -1.0, 1.5, 0.0, 0.0])  # grasp point about 4 cm above the counter
TRAY_ORIGIN = (0.30, -0.60)  # clear of the mugs these tests grasp near y = 0
BIG, SMALL = MUG_TYPES["big"], MUG_TYPES["small"]


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _with_cell(
    arm: ArmModel,
    mugs: list[SimMug],
    body: Callable[[KinematicCell], Awaitable[T]],
    *,
    q0: np.ndarray = Q_LOW,
) -> tuple[KinematicCell, T]:
    """Open the cell on a simulated clock, run ``body`` on it, close it; the cell and what ``body`` gave."""
    clock = SimulatedClock()

    async def main() -> tuple[KinematicCell, T]:
        cell, close = await start_kinematic_cell(
            mugs,
            GEOMETRY,
            tray_origin_m=TRAY_ORIGIN,
            tray_size_m=(0.332, 0.374),
            clock=clock,
            holding_threshold_n=1.0,
            arm=arm,
            q0=q0,
        )
        try:
            return cell, await body(cell)
        finally:
            await close()

    return clock.run(main())


def _mug_between_pads(arm: ArmModel, q: np.ndarray, kind: str = "big") -> SimMug:
    p, r = arm.fk(q)
    axis = p + r[:, 1] * (GEOMETRY[kind].diameter_m / 2 - arm.gripper.thumb_width_m)
    return SimMug("a", kind, float(axis[0]), float(axis[1]))


def _move(names: tuple[str, ...], a: np.ndarray, b: np.ndarray, seconds: float) -> JointTrajectory:
    s = np.linspace(0.0, 1.0, 11)
    return JointTrajectory(names, s * seconds, a + np.outer(s, b - a), label="test")


def test_the_arm_follows_a_trajectory_through_the_servo_chain_and_ends_at_the_goal(arm: ArmModel) -> None:
    goal = Q_LOW + np.array([0.5, -0.2, 0.1, 0.0, 0.3])

    async def go(cell: KinematicCell) -> tuple[float, int]:
        t0 = cell.world.clock.monotonic()
        seen = cell.servo_sim.packets_seen
        await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, goal, 1.0))
        return cell.world.clock.monotonic() - t0, cell.servo_sim.packets_seen - seen

    cell, (took, packets) = _with_cell(arm, [], go)
    assert 0.95 <= took < 1.2  # the trajectory's own timing (its last goal goes out at 0.98 s), settled
    assert packets >= 50  # a sync write and a read of the five joints every 20 ms, as bytes on the chain
    assert np.allclose(cell.world.q, goal, atol=0.03)  # within the driver's settle tolerance


def test_a_servo_asked_for_more_than_it_can_moves_at_its_no_load_speed(arm: ArmModel) -> None:
    goal = Q_LOW + np.array([2.0, 0.0, 0.0, 0.0, 0.0])

    async def go(cell: KinematicCell) -> float:
        await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, goal, 0.05))  # 40 rad/s asked
        return float(cell.world.q[0])

    _, reached = _with_cell(arm, [], go)
    # The driver settles for at most 2 s after the 0.05 s trajectory; the MX-64T turns 6.6 rad/s at most, and
    # the driver asks it for at most 3 rad/s.
    assert reached == pytest.approx(2.0, abs=0.03)  # settled


def test_a_cancelled_move_leaves_the_arm_part_way(arm: ArmModel) -> None:
    goal = Q_LOW + np.array([1.0, 0.0, 0.0, 0.0, 0.0])

    async def go(cell: KinematicCell) -> float:
        task = asyncio.create_task(cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, goal, 1.0)))
        await cell.world.clock.sleep(0.25)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await cell.world.clock.sleep(0.5)
        return float(cell.world.q[0])

    _, stopped = _with_cell(arm, [], go)
    assert 0.2 < stopped < 0.35  # about a quarter of the way, held there


def test_a_trajectory_outside_the_joint_limits_is_refused_before_moving(arm: ArmModel) -> None:
    bad = Q_LOW.copy()
    bad[1] = 1.0

    async def go(cell: KinematicCell) -> None:
        with pytest.raises(
            LimitViolation, match=r"^joint shoulder_lift \(servo 2\) goal 0\.4000 rad is outside"
        ):
            await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, bad, 1.0))

    cell, _ = _with_cell(arm, [], go)
    assert np.allclose(cell.world.q, Q_LOW, atol=0.01)


def test_closing_on_a_mug_raises_the_pad_force_and_the_mug_follows_the_gripper(arm: ArmModel) -> None:
    mug = _mug_between_pads(arm, Q_LOW)

    async def go(cell: KinematicCell) -> None:
        result = await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        assert result.held
        assert result.force_n >= 2.0
        assert result.aperture_m < 0.091  # the pads squeeze the big mug's 91 mm brim
        await cell.world.clock.sleep(0.1)
        assert cell.force.holding()
        reading = cell.force.latest()
        assert reading is not None
        assert reading.force_n >= 2.0  # the FSR reader's own reading of the Arduino's samples
        lifted = Q_LOW + np.array([0.3, -0.2, 0.0, 0.0, 0.0])
        await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, lifted, 1.0))
        moved = cell.world.mugs["a"]
        assert moved.where == "gripper"
        assert math.hypot(moved.x_m - mug.x_m, moved.y_m - mug.y_m) > 0.05

    cell, _ = _with_cell(arm, [mug], go)
    assert cell.world.mugs["a"].where == "counter"  # closing the cell turned the torque off: it fell


def test_closing_on_nothing_does_not_hold(arm: ArmModel) -> None:
    async def go(cell: KinematicCell) -> tuple[bool, str | None, float]:
        result = await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.04)
        return result.held, result.reason, result.aperture_m

    cell, (held, reason, aperture) = _with_cell(arm, [SimMug("far", "big", -0.3, 0.4)], go)
    assert not held
    assert str(reason).startswith("aperture ")
    assert aperture < 0.04
    assert not cell.force.holding()


def test_a_slipping_grasp_fails_and_pushes_the_mug_away(arm: ArmModel) -> None:
    mug = _mug_between_pads(arm, Q_LOW)

    async def go(cell: KinematicCell) -> bool:
        cell.world.slip_next_grasp()
        return (await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)).held

    cell, held = _with_cell(arm, [mug], go)
    assert not held
    after = cell.world.mugs["a"]
    assert math.hypot(after.x_m - mug.x_m, after.y_m - mug.y_m) == pytest.approx(0.04)
    assert after.where == "counter"


def test_a_dropped_mug_stops_the_force_and_lands_where_it_was(arm: ArmModel) -> None:
    async def go(cell: KinematicCell) -> tuple[str | None, bool]:
        await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        dropped = cell.world.drop_held_mug()
        await cell.world.clock.sleep(0.2)
        return dropped, cell.force.holding()

    cell, (dropped, holding) = _with_cell(arm, [_mug_between_pads(arm, Q_LOW)], go)
    assert dropped == "a"
    assert not holding
    assert cell.world.mugs["a"].where == "counter"


def test_a_mug_released_over_the_tray_lands_on_the_tray(arm: ArmModel) -> None:
    async def go(cell: KinematicCell) -> None:
        await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        cell.world.tray_origin_m = (cell.world.mugs["a"].x_m - 0.1, cell.world.mugs["a"].y_m - 0.1)
        await cell.gripper.open()

    cell, _ = _with_cell(arm, [_mug_between_pads(arm, Q_LOW)], go)
    assert cell.world.mugs["a"].where == "tray"
    assert cell.world.held is None


def test_a_partial_opening_lets_go_and_stops_short_of_fully_open(arm: ArmModel) -> None:
    async def go(cell: KinematicCell) -> tuple[float, float]:
        held = await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        await cell.gripper.open(0.091 + 0.006)
        partly = (await cell.gripper.read()).aperture_m
        return held.aperture_m, partly

    cell, (grasped, partly) = _with_cell(arm, [_mug_between_pads(arm, Q_LOW)], go)
    assert cell.world.held is None  # the pads left the brim
    assert grasped < 0.091 < partly
    assert partly == pytest.approx(0.097, abs=0.003)  # within the servo's ticks
    assert cell.world.aperture_m == pytest.approx(partly, abs=0.003)


def test_an_unplugged_bus_fails_every_device_call_as_on_the_robot(arm: ArmModel) -> None:
    async def go(cell: KinematicCell) -> None:
        cell.servo_sim.unplug()
        with pytest.raises(BusLost, match=r"^servo bus inprocess:ttyDXL is gone"):
            await cell.arm.read_joints()
        cell.servo_sim.replug()

    _with_cell(arm, [], go)


def test_an_overloaded_gripper_servo_goes_limp_and_the_mug_falls(arm: ArmModel) -> None:
    async def go(cell: KinematicCell) -> None:
        await cell.gripper.close_on_mug(force_threshold_n=2.0, min_aperture_m=0.02)
        assert cell.world.held == "a"
        cell.servo_sim.overload(6)
        with pytest.raises(ServoFault, match="overload"):
            await cell.gripper.read()

    cell, _ = _with_cell(arm, [_mug_between_pads(arm, Q_LOW)], go)
    assert cell.world.held is None
    assert cell.world.mugs["a"].where == "counter"


def test_a_servo_cooled_and_cleared_after_overheating_moves_the_arm_again(arm: ArmModel) -> None:
    goal = Q_LOW + np.array([0.3, 0.0, 0.0, 0.0, 0.0])

    async def go(cell: KinematicCell) -> float:
        cell.servo_sim.overheat(1)
        with pytest.raises(ServoFault, match="overheating"):
            await cell.arm.read_joints()
        cell.servo_sim.overheat(1, on=False)
        assert await cell.health.clear() == ()  # the reset: the torque limit is written back
        await cell.arm.follow(_move(cell.arm.joint_names, Q_LOW, goal, 1.0))
        return float(cell.world.q[0])

    _, reached = _with_cell(arm, [], go)
    assert reached == pytest.approx(0.3, abs=0.03)  # powered again, not left limp where it stood


def test_the_camera_sees_the_counter_mugs_through_the_frame_checks(arm: ArmModel) -> None:
    mugs = [SimMug("a", "big", 0.3, 0.4), SimMug("b", "small", 0.1, 0.45)]

    async def go(cell: KinematicCell) -> list[str]:
        seen = await cell.observer.observe()
        assert sorted(d.type for d in seen.detections) == ["big", "small"]
        cell.camera.set_fault("bad_frame")
        with pytest.raises(CameraFault, match=r"^camera: bad frame \(NaN depth\)$"):
            await cell.observer.observe()
        cell.camera.clear()
        cell.camera.set_fault("stale")
        await cell.world.clock.sleep(5.0)
        with pytest.raises(CameraFault, match=r"^camera: frame 5\.0 s old$"):
            await cell.observer.observe()
        return [d.type for d in seen.detections]

    _with_cell(arm, mugs, go)


def test_the_truth_detector_adds_seeded_noise_and_no_ids() -> None:
    truth = [
        Detection("big", 0.3, 0.4, False, 0.0, 1.0, "secret"),
        Detection("small", 0.1, 0.45, False, 0.0, 1.0),
    ]

    def look(seed: int) -> list[Detection]:
        clock = SimulatedClock()
        camera = TruthCamera(lambda: truth, clock=clock)
        detector = TruthDetector(camera, {"big": BIG, "small": SMALL}, noise_m=0.002, seed=seed)
        return detector.detect(clock.run(camera.capture()))

    first, again, other = look(1), look(1), look(2)
    assert first == again
    assert first != other
    assert [d.mug_id for d in first] == ["", ""]
    assert all(
        abs(d.x_m - t.x_m) < 0.01 and abs(d.y_m - t.y_m) < 0.01 for d, t in zip(first, truth, strict=True)
    )
    assert all(0.5 <= d.confidence <= 1.0 for d in first)


def test_a_stale_frame_shows_the_mugs_as_they_stood_when_it_was_taken() -> None:
    truth = [Detection("big", 0.3, 0.4, False, 0.0, 1.0)]
    clock = SimulatedClock()
    camera = TruthCamera(lambda: truth, clock=clock)
    detector = TruthDetector(camera, {"big": BIG}, noise_m=0.0, yaw_noise_rad=0.0)
    old = clock.run(camera.capture())
    truth.clear()
    assert [d.x_m for d in detector.detect(old)] == [0.3]
    assert detector.detect(clock.run(camera.capture())) == []


def test_a_depth_preview_is_published_as_16_bit_millimetres() -> None:
    import base64

    from daemon.messages import depth_preview

    depth = np.array([[0.0, 1.25], [np.nan, 70.0]], dtype=np.float32)
    preview = depth_preview(depth)
    assert (preview.width, preview.height, preview.encoding) == (2, 2, "uint16_mm_le_base64")
    values = np.frombuffer(base64.b64decode(preview.data), dtype="<u2").reshape(2, 2)
    assert values.tolist() == [[0, 1250], [0, 65535]]
