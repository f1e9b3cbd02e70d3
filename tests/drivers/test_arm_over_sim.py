"""DynamixelArm and DynamixelGripper driving the real dynamixel-sdk against the simulated servo chain: on the
in-process transport and a simulated clock, and (where the transport is the point) on a pty and the wall
clock."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.clock import SimulatedClock
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
from drivers.interfaces import ArmDriver, Clock, ForceReading, GripperDriver, JointTrajectory
from drivers.sim.plant import FirstOrderPlant, ServoPlant
from drivers.sim.servo_chain import ServoChainSimulator, default_chain
from tests.fakes.devices import (
    PATIENT_S,
    TRANSPORTS,
    MugBetweenPads,
    PlantForceSensor,
    opener,
    run_on,
    serving,
)

X_CHAIN = ((1, "XL430-W250"), (2, "XM430-W350"), (3, "XL330-M288"))


def x_joints() -> tuple[JointSpec, ...]:
    return tuple(JointSpec(f"j{i}", i, m, -2.0, 2.0) for i, m in X_CHAIN)


def chain_on(sim: ServoChainSimulator, clock: Clock, expected: object, **kw: object) -> ServoChain:
    """The driver's chain on ``sim``, whichever transport it is on (in-process an answer is there before
    the driver waits for it: a servo that does not answer costs only a short timeout)."""
    config = BusConfig(sim.device_path, protocol=sim.protocol)
    return ServoChain(
        config,
        expected,  # type: ignore[arg-type]
        clock=clock,
        open_serial=opener(sim),
        read_timeout_s=0.01 if sim.in_process else PATIENT_S,
        **kw,  # type: ignore[arg-type]
    )


def plant(clock: Clock) -> ServoPlant:
    return FirstOrderPlant(clock=clock.monotonic, tau_s=0.02)


def test_arm_joint_order_follows_the_thesis_chain() -> None:
    assert tuple(j.name for j in thesis_joints()) == tuple(n for n, _ in JOINT_SERVOS if n != "gripper")


@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.parametrize("protocol", [1, 2])
def test_arm_follows_a_trajectory_and_reads_back_the_final_pose(protocol: int, transport: str) -> None:
    chain_models = default_chain() if protocol == 1 else X_CHAIN
    joints = thesis_joints() if protocol == 1 else x_joints()

    async def body(clock: Clock) -> None:
        sim = ServoChainSimulator(chain_models, protocol=protocol, plant=plant(clock))  # type: ignore[arg-type]
        with serving(sim, transport, clock):
            async with chain_on(sim, clock, chain_models) as chain, DynamixelArm(chain, joints) as arm:
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

    run_on(transport, body)


def test_on_a_simulated_clock_a_trajectory_takes_its_duration_and_streams_at_50_hz() -> None:
    async def body(clock: Clock) -> tuple[float, int]:
        sim = ServoChainSimulator(default_chain()[:5], plant=plant(clock))
        with serving(sim, "inprocess", clock):
            async with (
                chain_on(sim, clock, default_chain()[:5]) as chain,
                DynamixelArm(chain, thesis_joints()) as arm,
            ):
                trajectory = JointTrajectory(
                    arm.joint_names, np.array([0.0, 2.0]), np.vstack([np.zeros(5), np.full(5, 0.3)])
                )
                packets = sim.packets_seen
                started = clock.monotonic()
                await arm.follow(trajectory)
                return clock.monotonic() - started, sim.packets_seen - packets

    took, packets = run_on("inprocess", body)
    # 2 s at 50 Hz: 100 ticks, each writing the goal one period ahead and reading every joint back (the
    # last goal goes out 20 ms before the end), then one settle read finds the arm there.
    assert took == pytest.approx(1.98)
    assert packets == 2 * 100 + 1


def test_a_goal_outside_the_software_limits_is_refused_before_anything_moves() -> None:
    joints = (JointSpec("shoulder_turn", 1, "MX-64T", -0.5, 0.5),)

    async def body(clock: Clock) -> None:
        with serving(ServoChainSimulator([(1, "MX-64T")]), "inprocess", clock) as sim:
            async with chain_on(sim, clock, [(1, "MX-64T")]) as chain, DynamixelArm(chain, joints) as arm:
                seen = sim.packets_seen
                trajectory = JointTrajectory(
                    arm.joint_names, np.array([0.0, 0.5, 1.0]), np.array([[0.0], [0.7], [0.0]])
                )
                with pytest.raises(LimitViolation) as raised:
                    await arm.follow(trajectory)
                assert str(raised.value) == (
                    "joint shoulder_turn (servo 1) goal 0.7000 rad is outside its limits [-0.5000, 0.5000] "
                    "rad; nothing was sent"
                )
                assert sim.packets_seen == seen

    run_on("inprocess", body)


def test_every_chain_mismatch_is_reported_in_one_error_and_torque_stays_off() -> None:
    chain_models = ((1, "MX-64T"), (2, "MX-28T"), (3, "AX-12A"))

    async def body(clock: Clock) -> None:
        found = [(1, "MX-64T"), (2, "MX-106T"), (4, "AX-12A")]
        with serving(ServoChainSimulator(found), "inprocess", clock) as sim:
            with pytest.raises(ChainMismatch) as raised:
                async with chain_on(sim, clock, chain_models):
                    pass
            assert str(raised.value) == (
                f"servo chain on {sim.device_path} does not match the config: servo 2 is a MX-106T, "
                "configured as MX-28T; servo 3 (AX-12A) does not answer. Fix the ids with `dishbot servo "
                "scan` / `dishbot servo set-id`; torque was not enabled"
            )
            assert [sim.servo(i).get("torque_enable") for i in (1, 2, 4)] == [0, 0, 0]

    run_on("inprocess", body)


def test_shutdown_parks_the_arm_then_turns_the_torque_off() -> None:
    chain_models = default_chain()[:5]
    park = (0.0, -0.4, 0.6, 0.3, 0.0)

    async def body(clock: Clock) -> None:
        with serving(ServoChainSimulator(chain_models, plant=plant(clock)), "inprocess", clock) as sim:
            async with chain_on(sim, clock, chain_models) as chain:
                async with DynamixelArm(chain, thesis_joints(), park_rad=park, park_speed_rad_s=3.0) as arm:
                    assert all(sim.servo(i).get("torque_enable") == 1 for i in range(1, 6))
                np.testing.assert_allclose(arm.last_state.position_rad, park, atol=0.03)  # type: ignore[union-attr]
                assert all(sim.servo(i).get("torque_enable") == 0 for i in range(1, 6))

    run_on("inprocess", body)


def test_cancelling_a_trajectory_holds_the_arm_where_it_is() -> None:
    chain_models = ((1, "MX-64T"),)
    joints = (JointSpec("shoulder_turn", 1, "MX-64T", -3.0, 3.0),)

    async def body(clock: Clock) -> None:
        with serving(ServoChainSimulator(chain_models, plant=plant(clock)), "inprocess", clock) as sim:
            async with chain_on(sim, clock, chain_models) as chain, DynamixelArm(chain, joints) as arm:
                trajectory = JointTrajectory(arm.joint_names, np.array([0.0, 2.0]), np.array([[0.0], [2.0]]))
                task = asyncio.create_task(arm.follow(trajectory))
                await clock.sleep(0.5)
                task.cancel()
                with pytest.raises(asyncio.CancelledError):
                    await task
                held = (await arm.read_joints()).position_rad[0]
                await clock.sleep(0.3)
                assert held == pytest.approx(0.5, abs=0.05)  # half a second into a 1 rad/s move
                assert abs((await arm.read_joints()).position_rad[0] - held) < 0.05

    run_on("inprocess", body)


def gripper_setup(clock: Clock, contact_aperture_m: float | None) -> tuple[GripperSpec, MugBetweenPads]:
    spec = GripperSpec()
    contact = spec.angle_for(contact_aperture_m) if contact_aperture_m is not None else None
    pads = MugBetweenPads(spec.servo_id, contact, clock=clock.monotonic, stiffness_n_per_rad=200.0)
    return spec, pads


@contextlib.asynccontextmanager
async def gripper_on_pads(
    clock: Clock, spec: GripperSpec, pads: MugBetweenPads
) -> AsyncIterator[DynamixelGripper]:
    """The gripper driver on a one-servo in-process chain whose pads close on ``pads``; its FSR reads them."""
    with serving(ServoChainSimulator([(6, "AX-12A")], plant=pads), "inprocess", clock) as sim:
        async with (
            chain_on(sim, clock, [(6, "AX-12A")]) as chain,
            DynamixelGripper(chain, spec, PlantForceSensor(pads, clock)) as gripper,
        ):
            yield gripper


def test_gripper_holds_a_mug_when_the_force_passes_the_threshold() -> None:
    async def body(clock: Clock) -> None:
        spec, pads = gripper_setup(clock, 0.074)  # small mug's brim diameter, §5.3
        async with gripper_on_pads(clock, spec, pads) as gripper:
            assert isinstance(gripper, GripperDriver)
            await gripper.open()
            result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
            assert result.held
            assert result.force_n >= 1.0
            assert result.aperture_m == pytest.approx(0.074, abs=0.004)

    run_on("inprocess", body)


def test_gripper_keeps_squeezing_the_mug_after_the_grasp_and_through_a_stop() -> None:
    async def body(clock: Clock) -> None:
        spec, pads = gripper_setup(clock, 0.074)
        async with gripper_on_pads(clock, spec, pads) as gripper:
            await gripper.open()
            result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
            assert result.held
            await clock.sleep(0.5)
            assert pads.force_n() >= 1.0  # the goal stays past contact: the squeeze does not relax
            await gripper.stop()  # a pause mid-carry
            await clock.sleep(0.2)
            assert pads.force_n() >= 1.0
            await gripper.open()
            await gripper.stop()
            assert pads.force_n() == 0.0

    run_on("inprocess", body)


def test_gripper_lets_go_opening_only_as_far_as_asked_and_never_closes_to_get_there() -> None:
    async def body(clock: Clock) -> None:
        spec, pads = gripper_setup(clock, 0.074)
        async with gripper_on_pads(clock, spec, pads) as gripper:
            await gripper.open()
            assert (await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)).held
            await gripper.open(0.080)  # 6 mm wider than the mug: let go between close neighbours
            assert (await gripper.read()).aperture_m == pytest.approx(0.080, abs=0.004)
            assert pads.force_n() == 0.0
            await gripper.open(0.060)  # narrower than it is: stays where it is
            assert (await gripper.read()).aperture_m == pytest.approx(0.080, abs=0.004)
            await gripper.open(1.0)  # beyond the stop: fully open
            assert (await gripper.read()).aperture_m == pytest.approx(spec.open_aperture_m, abs=0.004)

    run_on("inprocess", body)


def test_gripper_reports_a_missed_grasp_when_the_aperture_gets_too_small() -> None:
    async def body(clock: Clock) -> None:
        spec, pads = gripper_setup(clock, None)
        async with gripper_on_pads(clock, spec, pads) as gripper:
            await gripper.open()
            result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
            assert not result.held
            assert result.aperture_m < 0.03
            assert result.reason.startswith("aperture 0.0")
            assert "fell below 0.030 m before the force passed 1.00 N" in result.reason

    run_on("inprocess", body)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_fault_events_reach_the_event_loop_listener_before_the_failed_call_returns(transport: str) -> None:
    async def body(clock: Clock) -> list[DeviceEvent]:
        events: list[DeviceEvent] = []
        with serving(ServoChainSimulator([(1, "MX-28T")]), transport, clock) as sim:
            async with chain_on(sim, clock, [(1, "MX-28T")], on_event=events.append) as chain:
                sim.overload(1)
                with pytest.raises(Exception, match="overload"):
                    await chain.call(lambda bus: bus.read_states([1]))
                assert len(events) == 1
        return events

    events = run_on(transport, body)
    assert [(e.kind, e.device, e.detail["faults"]) for e in events] == [
        ("servo_fault", "servo/1", ["overload"])
    ]


class FrozenForceSensor:
    """An FSR whose last reading, high, stopped updating (the Arduino was unplugged mid-grasp)."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock

    def latest(self) -> ForceReading | None:
        return ForceReading(self.clock.monotonic() - 5.0, 9.0, 900, 1)

    def holding(self) -> bool:
        return True


def test_a_frozen_force_reading_never_counts_as_a_grasp() -> None:
    async def body(clock: Clock) -> None:
        spec, pads = gripper_setup(clock, None)
        with serving(ServoChainSimulator([(6, "AX-12A")], plant=pads), "inprocess", clock) as sim:
            async with (
                chain_on(sim, clock, [(6, "AX-12A")]) as chain,
                DynamixelGripper(chain, spec, FrozenForceSensor(clock)) as gripper,
            ):
                await gripper.open()
                result = await gripper.close_on_mug(force_threshold_n=1.0, min_aperture_m=0.03)
                assert not result.held
                assert result.force_n == 0.0

    run_on("inprocess", body)


def test_a_goal_a_rounding_error_past_a_limit_is_sent_at_the_limit() -> None:
    """A plan up to a joint's limit, computed in floating point, can end 1e-12 rad past it: that is the
    limit (an encoder step is a thousand times more), not a violation; 1e-3 rad past is one."""
    joints = (JointSpec("shoulder_turn", 1, "MX-64T", -0.5, 0.5),)

    async def body(clock: Clock) -> None:
        with serving(ServoChainSimulator([(1, "MX-64T")]), "inprocess", clock) as sim:
            async with chain_on(sim, clock, [(1, "MX-64T")]) as chain, DynamixelArm(chain, joints) as arm:
                edge = -0.5 - 1e-12
                await arm.follow(
                    JointTrajectory(arm.joint_names, np.array([0.0, 0.5]), np.array([[0.0], [edge]]))
                )
                state = await arm.read_joints()
                assert -0.5 - 2e-3 < state.position_rad[0] < -0.4  # on its way to the limit, not past it
                with pytest.raises(LimitViolation):
                    await arm.follow(
                        JointTrajectory(arm.joint_names, np.array([0.0, 0.5]), np.array([[-0.5], [-0.501]]))
                    )

    run_on("inprocess", body)


def _ticks_one_at_a_time(
    arm: DynamixelArm, times: np.ndarray, positions: np.ndarray
) -> list[dict[int, tuple[float, float]]]:
    """The control loop's goals as it computed them before they were computed at once: one interpolation
    per tick, the goals limit-checked and clamped one tick at a time."""
    duration = float(times[-1])
    columns = [np.ascontiguousarray(positions[:, k]) for k in range(positions.shape[1])]
    out = []
    tick = 0
    while True:
        t = min((tick + 1) * arm.period_s, duration)
        at = np.array([t - arm.period_s, t])
        both = np.array([np.interp(at, times, column) for column in columns])
        here, target = both[:, 0], both[:, 1]
        speed = np.clip(np.abs(target - here) / arm.period_s * 1.2, 0.05, arm.max_speed_rad_s)
        arm.check_limits(target)
        out.append(
            {
                j.servo_id: (min(max(float(target[k]), j.min_rad), j.max_rad), float(speed[k]))
                for k, j in enumerate(arm.joints)
            }
        )
        if t >= duration:
            return out
        tick += 1


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    steps=st.lists(st.floats(0.0, 1.3), min_size=1, max_size=6),
    fractions=st.lists(st.floats(0.0, 1.0), min_size=7 * 5, max_size=7 * 5),
    rate_hz=st.sampled_from([50.0, 30.0, 100.0]),
)
def test_the_goals_computed_at_once_are_those_of_one_tick_at_a_time(
    steps: list[float], fractions: list[float], rate_hz: float
) -> None:
    """``DynamixelArm`` computes a trajectory's control ticks before the first goes out: the same goals and
    speeds, bit for bit, as computing each tick when it comes (the numbers the bus sends and the
    recordings hold), up to the joints' limits (a plan ending a rounding error past one is sent at it)."""
    joints = thesis_joints()
    clock = SimulatedClock()
    arm = DynamixelArm(ServoChain(BusConfig("inprocess:none"), [], clock=clock), joints, rate_hz=rate_hz)
    times = np.concatenate([[0.0], np.cumsum(steps)])
    n = len(times)
    low = np.array([j.min_rad for j in joints])
    high = np.array([j.max_rad for j in joints])
    positions = low + np.array(fractions[: n * len(joints)]).reshape(n, len(joints)) * (high - low)
    positions[-1, 0] = joints[0].max_rad + 1e-12  # a rounding error past a limit, sent at it
    if times[-1] > 0.0 and not np.all(np.diff(times) > 0.0):
        times = np.arange(n, dtype=np.float64) * 0.37  # interp wants increasing times
    assert arm._ticks(times, positions) == _ticks_one_at_a_time(arm, times, positions)
