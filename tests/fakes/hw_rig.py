"""The hardware backend's test rig: the real device stack (dynamixel-sdk, pyserial) on the pseudo-terminals of
the simulated servo chain and FSR Arduino, which is exactly the code path of the robot. Stand-ins are for the
physical world only: the pad force rises when the gripper servo closes past a mug's width, the counter holds
one mug until the job has put it on the tray, and a motion planner test double makes short, in-limit moves
(a real cycle takes half a minute of wall time)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from daemon.backend import Backend
from daemon.clock import RealClock
from daemon.config import Config, load_config, merge_tables
from daemon.hardware import open_hardware_backend
from daemon.zenoh_session import session_config
from drivers.interfaces import JointTrajectory
from drivers.sim import FsrSimulator, ServoChainSimulator, default_chain
from drivers.sim.plant import FirstOrderPlant
from drivers.stack import ARM_JOINTS, gripper_spec
from perception.interfaces import Detection, Observation
from planning.arm import ArmModel
from planning.interfaces import CyclePlan, MotionRefused, MugPose, Step, StepKind, TraySlot
from statechart.chart import CARRYING, CYCLE_PHASES
from tests.fakes import daemon as harness

ROBOT = "hwtest"
GRIPPER_ID = 6
# The pads touch the mug when the opening is down to 8 cm: the force then rises to a firm grip.
CONTACT_RAD = gripper_spec(ArmModel.load().gripper).angle_for(0.08)
GRIP_N = 3.0
# The rig's status wait (the robot's is 20 ms): a silent servo still fails in its 3 tries (0.75 s).
PATIENT_READ_TIMEOUT_S = 0.25
MUG = Detection("big", 0.1, 0.45, False, 0.0, 0.95)


@dataclass
class Rig:
    """The simulated devices behind the hardware backend and the knobs of the physical world."""

    servos: ServoChainSimulator
    fsr: FsrSimulator
    plant: FirstOrderPlant
    config: Config
    placed: list[str] = field(default_factory=list)

    def pad_force_n(self) -> float:
        return GRIP_N if self.plant.present(GRIPPER_ID)[0] >= CONTACT_RAD else 0.0


@contextlib.contextmanager
def rig(**overrides: Any) -> Any:
    """Simulated servo chain and FSR on pseudo-terminals, and a hardware config pointing at them."""
    plant = FirstOrderPlant(clock=RealClock().monotonic)  # the robot's rig: the wall clock
    holder: list[Rig] = []
    with (
        ServoChainSimulator(default_chain(), plant=plant) as servos,
        FsrSimulator(lambda: holder[0].pad_force_n() if holder else 0.0) as fsr,
    ):
        base: dict[str, Any] = {
            "robot_id": ROBOT,
            "backend": "hardware",
            "planner": {"method": "bh"},
            "daemon": {"drop_check_period_s": 0.01},
            "hardware": {
                "servo_port": servos.device_path,
                "camera": "none",
                # A loaded test machine (load 7) sometimes runs the simulator's thread 100-250 ms late:
                # past the robot's status wait, a late answer would be a silent servo (BusTimeout).
                "read_timeout_s": PATIENT_READ_TIMEOUT_S,
                "fsr": {"port": fsr.device_path},
            },
        }
        config = load_config(overrides=merge_tables(base, overrides))
        holder.append(Rig(servos, fsr, plant, config))
        yield holder[0]


class CounterStandIn:
    """The counter as a camera would report it: one mug until the job placed it (``placed()``)."""

    def __init__(self, placed: Callable[[], bool]) -> None:
        self._placed = placed

    async def observe(self) -> Observation:
        return Observation(0.0, () if self._placed() else (MUG,), meta={"source": "stand-in"})


class ShortMoves:
    """A motion planner test double: each move turns the shoulder 0.05 rad and back, briefly; moves while a
    mug is carried last longer so a test can act during them, and the phases of ``phase_s`` last as long as
    it says (a test that acts in one phase need not wait through the others)."""

    def __init__(
        self, *, move_s: float = 0.1, carry_s: float = 0.4, phase_s: Mapping[str, float] | None = None
    ) -> None:
        self.move_s = move_s
        self.carry_s = carry_s
        self.phase_s = dict(phase_s or {})

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        steps = []
        q = np.asarray(start_q, dtype=np.float64)
        for k, phase in enumerate(CYCLE_PHASES):
            leaf = phase.split(".")[1]
            if leaf == "close":
                steps.append(Step(phase, StepKind.CLOSE))
            elif leaf == "release":
                steps.append(Step(phase, StepKind.OPEN))
            elif leaf != "verify":
                goal = q.copy()
                goal[0] = 0.05 * (k % 2)
                seconds = self.phase_s.get(phase, self.carry_s if phase in CARRYING else self.move_s)
                steps.append(Step(phase, StepKind.MOVE, _line(q, goal, seconds, f"{phase}:{mug.mug_id}")))
                q = goal
        return CyclePlan(mug.mug_id, tuple(steps), duration_s=1.0, energy_j=1.0)

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        """The mug the slot names: nothing blocks it on this counter."""
        mug = next((m for m in counter if m.mug_id == slot.mug_id), None)
        if mug is None:
            raise MotionRefused(f"slot for {slot.mug_id}: the mug is not on the counter")
        return mug, self.plan_cycle(start_q, mug, slot, on_tray, counter=counter)

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        return _line(np.asarray(start_q), np.asarray(goal_q), self.move_s, label)


def _line(a: np.ndarray, b: np.ndarray, seconds: float, label: str) -> JointTrajectory:
    s = np.linspace(0.0, 1.0, 6)
    return JointTrajectory(ARM_JOINTS, s * seconds, a + np.outer(s, b - a), label=label)


@dataclass
class RigDaemon:
    """A daemon running on the rig's hardware backend, and what a Zenoh subscriber received from it."""

    backend: Backend
    motion: ShortMoves = field(default_factory=ShortMoves)
    events: list[dict[str, Any]] = field(default_factory=list)
    states: list[str] = field(default_factory=list)
    session: Any = None
    endpoint: str = ""

    def kinds(self) -> list[str]:
        return [str(e["kind"]) for e in self.events]

    def event(self, kind: str) -> dict[str, Any]:
        return next(e for e in self.events if e["kind"] == kind)

    async def until(self, condition: Callable[[], bool], *, timeout_s: float = 15.0) -> None:
        async with asyncio.timeout(timeout_s):
            while not condition():  # noqa: ASYNC110 (the subscriber's callbacks feed the condition)
                await asyncio.sleep(0.01)

    def reached(self, *states: str) -> bool:
        """Whether the ``events`` stream announced a transition into one of ``states``: every event the job
        published before it has arrived too (one key keeps its order)."""
        return any(e["kind"] == "transition" and e["dest"] in states for e in self.events)

    async def command(self, verb: str, body: dict[str, Any] | None = None) -> dict[str, Any]:
        payload = json.dumps(body or {}).encode()

        def query() -> dict[str, Any]:
            replies = list(self.session.get(f"dishbot/{ROBOT}/cmd/{verb}", payload=payload, timeout=5.0))
            reply: dict[str, Any] = json.loads(replies[0].ok.payload.to_bytes())
            return reply

        return await asyncio.to_thread(query)

    @property
    def state(self) -> str:
        """The last state the subscriber saw published."""
        return self.states[-1] if self.states else ""


@contextlib.asynccontextmanager
async def running_daemon(
    r: Rig, tmp_path: Path, *, carry_s: float = 0.4, phase_s: Mapping[str, float] | None = None
) -> AsyncIterator[RigDaemon]:
    """The harness's daemon (``tests.fakes.daemon``) on the hardware backend of ``r`` over a real loopback
    Zenoh session, with a second session subscribed to ``events`` and ``state`` (what a monitor on another
    machine sees)."""
    backend = await open_hardware_backend(r.config)
    d = RigDaemon(backend, ShortMoves(carry_s=carry_s, phase_s=phase_s))
    backend = dataclasses.replace(
        backend, observer=CounterStandIn(lambda: "mug_placed" in d.kinds()), motion=d.motion
    )
    d.backend = backend
    loop = asyncio.get_running_loop()
    async with harness.running_daemon(r.config, backend, tmp_path) as running:
        d.endpoint = running.endpoint
        with zenoh.open(session_config(listen=[], connect=[d.endpoint])) as session:
            d.session = session

            def on_event(sample: zenoh.Sample) -> None:
                loop.call_soon_threadsafe(d.events.append, json.loads(sample.payload.to_bytes()))

            def on_state(sample: zenoh.Sample) -> None:
                state = json.loads(sample.payload.to_bytes())["state"]
                loop.call_soon_threadsafe(d.states.append, state)

            subs = [
                session.declare_subscriber(f"dishbot/{ROBOT}/events", on_event),
                session.declare_subscriber(f"dishbot/{ROBOT}/state", on_state),
            ]
            # The subscription has reached the daemon's session once a periodic state message comes through
            # (a fixed wait was not always long enough on a loaded machine).
            await d.until(lambda: bool(d.states), timeout_s=30.0)
            try:
                yield d
            finally:
                await running.stop(timeout_s=30.0)
                for sub in subs:
                    sub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it untyped
