"""DynamixelArm and DynamixelGripper driving the real dynamixel-sdk against the pty servo chain."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator

import numpy as np
import pytest

from description.thesis import JOINT_SERVOS
from drivers.dynamixel import (
    BusConfig,
    ChainMismatch,
    DeviceEvent,
    DynamixelArm,
    DynamixelGripper,
    GripperSpec,
    JointSpec,
    ServoChain,
    thesis_joints,
)
from drivers.errors import LimitViolation
from drivers.interfaces import ArmDriver, ForceReading, GripperDriver, JointTrajectory
from drivers.sim.plant import FirstOrderPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from tests.fakes.devices import PATIENT_S, MugBetweenPads, PlantForceSensor, async_test

X_CHAIN = ((1, "XL430-W250"), (2, "XM430-W350"), (3, "XL330-M288"))


def x_joints() -> tuple[JointSpec, ...]:
    return tuple(JointSpec(f"j{i}", i, m, -2.0, 2.0) for i, m in X_CHAIN)


def test_arm_joint_order_follows_the_thesis_chain() -> None:
    assert tuple(j.name for j in thesis_joints()) == tuple(n for n, _ in JOINT_SERVOS if n != "gripper")


@pytest.mark.parametrize("protocol", [1, 2])
@async_test
async def test_arm_follows_a_trajectory_and_reads_back_the_final_pose(protocol: int) -> None:
    chain_models = default_chain() if protocol == 1 else X_CHAIN
    joints = thesis_joints() if protocol == 1 else x_joints()
    with ServoChainSimulator(chain_models, protocol=protocol, plant=FirstOrderPlant(tau_s=0.02)) as sim:  # type: ignore[arg-type]
        config = BusConfig(sim.device_path, protocol=protocol)  # type: ignore[arg-type]
        async with (
            ServoChain(config, chain_models, read_timeout_s=PATIENT_S) as chain,
            DynamixelArm(chain, joints) as arm,
        ):
            assert isinstance(arm, ArmDriver)
            n = len(joints)
            goal = np.linspace(0.2, -0.3, n)
            trajectory = JointTrajectory(
                arm.joint_names, np.array([0.0, 0.4]), np.vstack([np.zeros(n), goal])
            )
            await arm.follow(trajectory)
            state = await arm.read_joints()
            assert state.names == arm.joint_names
            np.testing.assert_allclose(state.position_rad, goal, atol=0.03)


@async_test
async def test_a_goal_outside_the_software_limits_is_refused_before_anything_moves() -> None:
    joints = (JointSpec("shoulder_turn", 1, "MX-64T", -0.5, 0.5),)
    with ServoChainSimulator([(1, "MX-64T")]) as sim:
        async with (
            ServoChain(BusConfig(sim.device_path), [(1, "MX-64T")], read_timeout_s=PATIENT_S) as chain,
            DynamixelArm(chain, joints) as arm,
        ):
            seen = sim.packets_seen
            trajectory = JointTrajectory(
                arm.joint_names, np.array([0.0, 0.5, 1.0]), np.array([[0.0], [0.7], [0.0]])
            )
            with pytest.raises(LimitViolation) as raised:
                await arm.follow(trajectory)
            assert str(raised.value) == (
                "joint shoulder_turn (servo 1) goal 0.7000 rad is outside its limits [-0.5000, 0.5000] rad; "
                "nothing was sent"
            )
            assert sim.packets_seen == seen


@async_test
async def test_every_chain_mismatch_is_reported_in_one_error_and_torque_stays_off() -> None:
    chain_models = ((1, "MX-64T"), (2, "MX-28T"), (3, "AX-12A"))
    with ServoChainSimulator([(1, "MX-64T"), (2, "MX-106T"), (4, "AX-12A")]) as sim:
        with pytest.raises(ChainMismatch) as raised:
            async with ServoChain(BusConfig(sim.device_path), chain_models, read_timeout_s=PATIENT_S):
                pass
        assert str(raised.value) == (
            f"servo chain on {sim.device_path} does not match the config: servo 2 is a MX-106T, "
            "configured as MX-28T; servo 3 (AX-12A) does not answer. Fix the ids with `dishbot servo scan` / "
            "`dishbot servo set-id`; torque was not enabled"
        )
        assert [sim.servo(i).get("torque_enable") for i in (1, 2, 4)] == [0, 0, 0]


@async_test
async def test_shutdown_parks_the_arm_then_turns_the_torque_off() -> None:
    chain_models = default_chain()[:5]
    park = (0.0, -0.4, 0.6, 0.3, 0.0)
    with ServoChainSimulator(chain_models, plant=FirstOrderPlant(tau_s=0.02)) as sim:
        async with ServoChain(BusConfig(sim.device_path), chain_models, read_timeout_s=PATIENT_S) as chain:
            async with DynamixelArm(chain, thesis_joints(), park_rad=park, park_speed_rad_s=3.0) as arm:
                assert all(sim.servo(i).get("torque_enable") == 1 for i in range(1, 6))
            np.testing.assert_allclose(arm.last_state.position_rad, park, atol=0.03)  # type: ignore[union-attr]
            assert all(sim.servo(i).get("torque_enable") == 0 for i in range(1, 6))


@async_test
async def test_cancelling_a_trajectory_holds_the_arm_where_it_is() -> None:
    chain_models = ((1, "MX-64T"),)
    joints = (JointSpec("shoulder_turn", 1, "MX-64T", -3.0, 3.0),)
    with ServoChainSimulator(chain_models, plant=FirstOrderPlant(tau_s=0.02)) as sim:
        async with (
            ServoChain(BusConfig(sim.device_path), chain_models, read_timeout_s=PATIENT_S) as chain,
            DynamixelArm(chain, joints) as arm,
        ):
            trajectory = JointTrajectory(arm.joint_names, np.array([0.0, 2.0]), np.array([[0.0], [2.0]]))
            task = asyncio.create_task(arm.follow(trajectory))
            await asyncio.sleep(0.5)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            held = (await arm.read_joints()).position_rad[0]
            await asyncio.sleep(0.3)
            assert 0.2 < held < 1.2
            assert abs((await arm.read_joints()).position_rad[0] - held) < 0.05


def gripper_setup(contact_aperture_m: float | None) -> tuple[GripperSpec, MugBetweenPads]:
    spec = GripperSpec()
    contact = spec.angle_for(contact_aperture_m) if contact_aperture_m is not None else None
    plant = MugBetweenPads(spec.servo_id, contact, stiffness_n_per_rad=200.0)
    return spec, plant


@contextlib.asynccontextmanager
async def gripper_on_pads(spec: GripperSpec, plant: MugBetweenPads) -> AsyncIterator[DynamixelGripper]:
    """The gripper driver on a one-servo pty chain whose pads close on ``plant``; its FSR reads the plant."""
    with ServoChainSimulator([(6, "AX-12A")], plant=plant) as sim:
        async with (
            ServoChain(BusConfig(sim.device_path), [(6, "AX-12A")], read_timeout_s=PATIENT_S) as chain,
            DynamixelGripper(chain, spec, PlantForceSensor(plant)) as gripper,
        ):
            yield gripper


@async_test
async def test_gripper_holds_a_mug_when_the_force_passes_the_threshold() -> None:
    spec, plant = gripper_setup(0.074)  # small mug's brim diameter, §5.3
    async with gripper_on_pads(spec, plant) as gripper:
        assert isinstance(gripper, GripperDriver)
        await gripper.open()
        result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
        assert result.held
        assert result.force_n >= 1.0
        assert result.aperture_m == pytest.approx(0.074, abs=0.004)


@async_test
async def test_gripper_keeps_squeezing_the_mug_after_the_grasp_and_through_a_stop() -> None:
    spec, plant = gripper_setup(0.074)
    async with gripper_on_pads(spec, plant) as gripper:
        await gripper.open()
        result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
        assert result.held
        await asyncio.sleep(0.5)
        assert plant.force_n() >= 1.0  # the goal stays past contact: the squeeze does not relax
        await gripper.stop()  # a pause mid-carry
        await asyncio.sleep(0.2)
        assert plant.force_n() >= 1.0
        await gripper.open()
        await gripper.stop()
        assert plant.force_n() == 0.0


@async_test
async def test_gripper_lets_go_opening_only_as_far_as_asked_and_never_closes_to_get_there() -> None:
    spec, plant = gripper_setup(0.074)
    async with gripper_on_pads(spec, plant) as gripper:
        await gripper.open()
        assert (await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)).held
        await gripper.open(0.080)  # 6 mm wider than the mug: let go between close neighbours
        assert (await gripper.read()).aperture_m == pytest.approx(0.080, abs=0.004)
        assert plant.force_n() == 0.0
        await gripper.open(0.060)  # narrower than it is: stays where it is
        assert (await gripper.read()).aperture_m == pytest.approx(0.080, abs=0.004)
        await gripper.open(1.0)  # beyond the stop: fully open
        assert (await gripper.read()).aperture_m == pytest.approx(spec.open_aperture_m, abs=0.004)


@async_test
async def test_gripper_reports_a_missed_grasp_when_the_aperture_gets_too_small() -> None:
    spec, plant = gripper_setup(None)
    async with gripper_on_pads(spec, plant) as gripper:
        await gripper.open()
        result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
        assert not result.held
        assert result.aperture_m < 0.03
        assert result.reason.startswith("aperture 0.0")
        assert "fell below 0.030 m before the force passed 1.00 N" in result.reason


@async_test
async def test_fault_events_reach_the_event_loop_listener() -> None:
    events: list[DeviceEvent] = []
    with ServoChainSimulator([(1, "MX-28T")]) as sim:
        async with ServoChain(
            BusConfig(sim.device_path), [(1, "MX-28T")], on_event=events.append, read_timeout_s=PATIENT_S
        ) as chain:
            sim.overload(1)
            with pytest.raises(Exception, match="overload"):
                await chain.call(lambda bus: bus.read_states([1]))
            await asyncio.sleep(0.01)
    assert [(e.kind, e.device, e.detail["faults"]) for e in events] == [
        ("servo_fault", "servo/1", ["overload"])
    ]


class FrozenForceSensor:
    """An FSR whose last reading, high, stopped updating (the Arduino was unplugged mid-grasp)."""

    def latest(self) -> ForceReading | None:
        return ForceReading(time.monotonic() - 5.0, 9.0, 900, 1)

    def holding(self) -> bool:
        return True


@async_test
async def test_a_frozen_force_reading_never_counts_as_a_grasp() -> None:
    spec, plant = gripper_setup(None)
    with ServoChainSimulator([(6, "AX-12A")], plant=plant) as sim:
        async with (
            ServoChain(BusConfig(sim.device_path), [(6, "AX-12A")], read_timeout_s=PATIENT_S) as chain,
            DynamixelGripper(chain, spec, FrozenForceSensor()) as gripper,
        ):
            await gripper.open()
            result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
            assert not result.held
            assert result.force_n == 0.0
