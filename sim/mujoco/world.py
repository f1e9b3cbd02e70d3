"""The simulated cell's physics: MuJoCo stepping the arm, the gripper and the mugs, in lockstep with a clock.

``SimWorld`` is the physical world behind the simulated devices. The pseudo-terminal servo chain
(``drivers.sim``) talks to it through the ``ServoPlant`` methods (``set_goal``, ``present``, ``set_torque``),
the FSR simulator reads ``gripper_force_n``, the depth camera renders its state. Nothing above ``drivers/``
sees it, except tests and benchmarks, which may read the true mug poses (``mug_truths``) to judge the robot.

Servos are modelled as their firmware behaves: a goal and a moving speed go in, the internal set-point walks
towards the goal at that speed (capped at the no-load speed), and a torque-limited position controller — a
MuJoCo position actuator — follows the set-point. Mugs are held by friction between the pads; once a grasp is
confirmed (pad force above ``weld_force_n`` with the mug touching both pads) a weld equality is switched on so
a long carry does not creep, and it is switched off as soon as the jaw opens or the force falls, so a mug can
still slip, fall, tip and collide.

The world moves one of two ways. ``attach(clock)`` steps it by a simulated clock (``SteppedClock``): every
time the clock advances, the physics is stepped to the new time on the clock's thread, while no device is
being read, so every reader sees the world exactly at the clock's time and a run does not depend on the
machine's load. ``start()`` steps it in its own thread at real time × ``speed`` instead, for devices that keep
wall-clock time (the pseudo-terminal transport).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Final, Literal

import mujoco
import numpy as np
import structlog

from drivers.interfaces import SteppedClock
from sim.mujoco.arm import (
    ARM_PREFIX,
    FINGER_PAD_GEOM,
    FSR_PAD_GEOM,
    TCP_SITE,
    ArmMjcf,
)
from sim.mujoco.errors import SimModelError, SimWorldStopped

log = structlog.get_logger("sim.mujoco")

MUG_BODY_PREFIX: Final = "mug/"
# Where the arm stands when the world is built: upper arm up, forearm forward, gripper pointing down, well
# clear of the counter and the mugs (radians, by joint name).
READY_POSE_RAD: Final[dict[str, float]] = {
    "shoulder_turn": 0.0,
    "shoulder_lift": -1.5,
    "elbow_lift": 1.5,
    "wrist_lift": 0.0,
    "wrist_turn": 0.0,
    "gripper": 0.0,
}
WELD_PREFIX: Final = "grasp/"

Orientation = Literal["upright", "inverted", "tipped"]


@dataclass(frozen=True, slots=True)
class PhysicsConfig:
    """Solver settings and grasp thresholds; defaults keep a 12-mug cell many times faster than real time."""

    timestep_s: float = 0.002
    solver_iterations: int = 30
    # How often the grasp monitor, the force reading and the collision accounting run (simulated seconds).
    monitor_period_s: float = 0.004
    weld_force_n: float = 1.5  # pad force that confirms a grasp and welds the mug to the gripper
    release_force_n: float = 0.3  # below this for ``release_after_s`` the weld lets go
    release_after_s: float = 0.03
    release_opening_m: float = 0.003  # jaw opened this much past the grasp: let go
    # A held mug pressed onto something with more than this is no longer welded: friction alone holds it.
    support_force_n: float = 0.5
    max_batch_s: float = 0.02  # longest stretch stepped while holding the lock

    def __post_init__(self) -> None:
        checks = (
            ("timestep_s", self.timestep_s, 1e-4, 0.01),
            ("monitor_period_s", self.monitor_period_s, self.timestep_s, 0.1),
            ("weld_force_n", self.weld_force_n, 0.05, 100.0),
            ("release_force_n", self.release_force_n, 0.0, self.weld_force_n),
        )
        for name, value, lo, hi in checks:
            if not lo <= value <= hi:
                raise ValueError(f"PhysicsConfig.{name} = {value} is outside [{lo}, {hi}]")


@dataclass(frozen=True, slots=True)
class MugTruth:
    """Where a mug really is (for tests and benchmarks only; the robot must not see this)."""

    mug_id: str
    position_m: tuple[float, float, float]  # body origin in the world frame
    quat_wxyz: tuple[float, float, float, float]
    axis_z: float  # z component of the mug's axis (bottom to brim): 1 upright, -1 upside down
    held: bool
    speed_m_s: float

    @property
    def orientation(self) -> Orientation:
        if self.axis_z > math.cos(math.radians(20.0)):
            return "upright"
        if self.axis_z < -math.cos(math.radians(20.0)):
            return "inverted"
        return "tipped"


@dataclass(frozen=True, slots=True)
class HeldMug:
    """A mug to put in the gripper when a world is set to a state seen elsewhere (``SimWorld.hold``): its
    bottom (the body's origin) and axis (bottom to brim) in the world frame, its handle's yaw about the
    axis, and the grip: the jaw's opening on it and the pad force."""

    mug_id: str
    bottom_m: tuple[float, float, float]
    axis: tuple[float, float, float]
    yaw_rad: float
    aperture_m: float
    force_n: float


@dataclass(slots=True)
class _Servo:
    """A servo's fixed facts; its goal, speed and set-point live in the world's arrays at ``index``."""

    index: int
    servo_id: int
    joint: str
    actuator: int
    qpos_adr: int
    dof_adr: int
    lower: float
    upper: float
    max_speed: float
    stall_torque: float
    gainprm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    biasprm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    torque_on: bool = True


@dataclass(frozen=True, slots=True)
class ContactSample:
    """One monitor-tick contact between two watched bodies (used by the collision accounting): two mugs, or a
    mug and the gripper; its normal force is MuJoCo's (``mj_contactForce``)."""

    geom1: int
    geom2: int
    position: tuple[float, float, float]
    normal_force_n: float


@dataclass(slots=True)
class _GripContacts:
    contacts: list[ContactSample] = field(default_factory=list)
    pad_force_n: float = 0.0  # on the FSR
    support_force_n: float = 0.0  # on the held mug from anything but the gripper (a table, the tray, a mug)
    thumb_mugs: set[int] = field(default_factory=set)  # mugs touching the thumb side (the tool link)
    finger_mugs: set[int] = field(default_factory=set)


# What a contact's geom pair means while a mug is held (bits of a ``SimWorld._holding_table``): a possible
# collision, reported to the listeners; a push on the held mug from anything but the gripper.
_WATCHED: Final = np.uint8(1)
_SUPPORTING: Final = np.uint8(2)

# What a monitor tick without a watched contact sees (most ticks): read, never changed.
_NO_CONTACTS: Final = _GripContacts()

ContactListener = Callable[["SimWorld", float, Sequence[ContactSample]], None]


class SimWorld:
    """A MuJoCo model of the cell, stepped by a simulated clock or its own thread; also the servo chain's
    ``ServoPlant``.

    Build it with ``SimWorld(mjcf_xml, arm, mug_ids=...)`` (or ``sim.mujoco.cell`` which does it from
    the configured layout), then ``attach(clock)`` (lockstep with a simulated clock), or ``start()``/
    ``stop()`` (its own thread at real time × ``speed``; also as a context manager). Without either,
    ``step_for(seconds)`` advances it synchronously (tests).
    """

    def __init__(
        self,
        mjcf_xml: str,
        arm: ArmMjcf,
        *,
        mug_ids: Sequence[str],
        speed: float = 1.0,
        physics: PhysicsConfig | None = None,
        initial_pose_rad: Mapping[str, float] | None = None,
    ) -> None:
        if not (math.isfinite(speed) and 0.0 < speed <= 1000.0):
            raise ValueError(f"speed = {speed} must be in (0, 1000] (simulated seconds per wall second)")
        self.physics = physics or PhysicsConfig()
        self.speed = speed
        self.arm = arm
        self.mug_ids = tuple(mug_ids)
        _log_mujoco_warnings()
        self.model = self._compile(mjcf_xml)
        self.data = mujoco.MjData(self.model)
        # MuJoCo's counts of bad positions, velocities and accelerations (consecutive in mjtWarning): a state
        # it finds bad stops the world after the batch of steps, as non-finite positions do.
        first = int(mujoco.mjtWarning.mjWARN_BADQPOS)
        self._bad_state_counts = self.data.warning.number[first : first + 3]  # a live view
        # Held by the physics thread while it steps; take it to read or render a consistent state.
        self.lock = threading.RLock()
        self._servos = self._bind_servos()
        ordered = sorted(self._servos.values(), key=lambda sv: sv.index)
        # Index arrays to read every servo's state with one numpy operation per batch of steps.
        self._actuators = np.array([sv.actuator for sv in ordered], dtype=np.int64)
        self._qpos_adr = np.array([sv.qpos_adr for sv in ordered], dtype=np.int64)
        self._dof_adr = np.array([sv.dof_adr for sv in ordered], dtype=np.int64)
        self._stall = [sv.stall_torque for sv in ordered]
        # The servos' slices of ``data.ctrl`` (all set-points written at once) and of the positions,
        # velocities and actuator forces (read after every batch) when they are consecutive, as they are in
        # the cell's arm: a slice is cheaper than a fancy index, and selects the same numbers.
        self._ctrl_index = _as_slice(self._actuators)
        # ``data.ctrl`` itself (a view of MuJoCo's memory, as long-lived as ``data``) and each servo's element
        # of it: the set-point walk writes the set-points that moved, one element each.
        self._ctrl = self.data.ctrl
        self._actuator_list: list[int] = self._actuators.tolist()
        self._qpos_index = _as_slice(self._qpos_adr)
        self._qvel_index = _as_slice(self._dof_adr)
        # Goals, speeds and set-points as plain float lists: six servos walk faster in Python floats than
        # in numpy's per-call overhead (the same IEEE operations, so the same set-points to the last bit).
        self._goal = [0.0] * len(ordered)
        self._speed = [0.0] * len(ordered)
        self._setpoint = [0.0] * len(ordered)
        # Bumped by every new goal; the physics skips the set-point walk while it has reached the goals of the
        # latest bump (a generation rather than a flag: a goal written mid-step is never lost).
        self._goal_gen = 0
        self._settled_gen = -1
        # Each servo's (position, velocity, load) as of the last batch of steps, by index.
        self._present: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),) * len(ordered)
        # The physics moved since ``_present`` was taken (never set in the world's own thread).
        self._present_due = False
        self._mug_body = {m: self._id(mujoco.mjtObj.mjOBJ_BODY, MUG_BODY_PREFIX + m) for m in self.mug_ids}
        self._weld = {m: self._id(mujoco.mjtObj.mjOBJ_EQUALITY, WELD_PREFIX + m) for m in self.mug_ids}
        self._fsr_pad = self._id(mujoco.mjtObj.mjOBJ_GEOM, FSR_PAD_GEOM)
        self._finger_pad = self._id(mujoco.mjtObj.mjOBJ_GEOM, FINGER_PAD_GEOM)
        self._tool_body = int(self.model.geom_bodyid[self._fsr_pad])
        self._finger_body = int(self.model.geom_bodyid[self._finger_pad])
        self._tcp_site = self._id(mujoco.mjtObj.mjOBJ_SITE, TCP_SITE)
        self.geom_mug = self._geom_mug_index()
        self.geom_gripper = self._geom_gripper_mask()
        self._watched_pairs = self._watched_pair_table()
        # The same table flat, indexed by ``geom1 * ngeom + geom2`` (one lookup instead of a 2-D fancy
        # index), and for each mug held the table of what a pair means while it is held (by mug index).
        self._ngeom = int(self.model.ngeom)
        self._watched_flat = self._watched_pairs.ravel()
        self._holding_tables: dict[int, np.ndarray] = {}
        self._support_tables: dict[int, np.ndarray] = {}
        # A contact's geom pair (a row of ``data.contact.geom``, int32 as MuJoCo keeps ids) times this is
        # its key in the flat tables; the same integer type on both sides keeps the product one C loop.
        self._pair_key = np.array([self._ngeom, 1], dtype=np.int32)
        self._geom_mug_list: list[int] = self.geom_mug.tolist()
        self._geom_body_list: list[int] = self.model.geom_bodyid.tolist()
        self._mug_index = {m: i for i, m in enumerate(self.mug_ids)}
        self._gripper_servo = next(s for s in self._servos.values() if s.joint == "gripper")
        self._held: str | None = None
        self._held_aperture_m = 0.0
        self._held_force_n = 0.0
        self._low_force_since: float | None = None
        self._slipping: set[str] = set()
        self._gripper_geoms = np.flatnonzero(self.geom_gripper)
        self._gripper_friction = self.model.geom_friction[self._gripper_geoms].copy()
        self._force_n = 0.0
        self._next_monitor = 0.0
        self._listeners: list[ContactListener] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._failure: BaseException | None = None
        self._steps = 0  # physics steps since the initial settling (data.time == _steps * timestep)
        self._detach: Callable[[], None] | None = None
        self._epoch = 0.0  # the clock's time when the world was attached to it
        self.wall_stepping_s = 0.0
        self._settle_at_start(READY_POSE_RAD if initial_pose_rad is None else initial_pose_rad)

    # ------------------------------------------------------------------------------------------- building

    def _compile(self, mjcf_xml: str) -> mujoco.MjModel:
        try:
            spec = mujoco.MjSpec.from_string(mjcf_xml)
        except ValueError as e:
            raise SimModelError(f"MuJoCo refused the cell's MJCF: {e}") from e
        cfg = self.physics
        spec.option.timestep = cfg.timestep_s
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        spec.option.iterations = cfg.solver_iterations
        spec.option.ls_iterations = 10
        # Mugs at rest on the counter sleep (no contacts solved) until something touches them: a dozen
        # resting mugs otherwise cost most of the step.
        spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
        # By default MuJoCo answers a bad state by resetting the data (time back to 0, every body back at its
        # start) and stepping on, which would hide a divergence behind finite positions; without the reset
        # the state stays as it went bad and the world stops, saying when (``_run_steps``).
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        # Torsional and rolling friction on the mugs: without them a mug rocking on its rim walks across the
        # tray and a tipped one rolls off the table forever.
        for geom in spec.geoms:
            if geom.name.startswith(MUG_BODY_PREFIX) and geom.contype:
                geom.condim = 6
        tool = self.arm.tool_body
        for mug in self.mug_ids:
            if spec.body(MUG_BODY_PREFIX + mug) is None:
                raise SimModelError(f"the MJCF has no body {MUG_BODY_PREFIX + mug!r} for mug {mug!r}")
            spec.add_equality(
                name=WELD_PREFIX + mug,
                type=mujoco.mjtEq.mjEQ_WELD,
                objtype=mujoco.mjtObj.mjOBJ_BODY,
                name1=tool,
                name2=MUG_BODY_PREFIX + mug,
                active=0,
                solref=[0.01, 1.0],
            )
        try:
            return spec.compile()
        except ValueError as e:
            raise SimModelError(f"MuJoCo could not compile the cell: {e}") from e

    def _id(self, kind: mujoco.mjtObj, name: str) -> int:
        i = int(mujoco.mj_name2id(self.model, kind, name))
        if i < 0:
            raise SimModelError(f"the compiled cell has no {kind.name[6:].lower()} named {name!r}")
        return i

    def _bind_servos(self) -> dict[int, _Servo]:
        servos: dict[int, _Servo] = {}
        for index, s in enumerate(self.arm.servos):
            j = self._id(mujoco.mjtObj.mjOBJ_JOINT, s.mj_joint)
            a = self._id(mujoco.mjtObj.mjOBJ_ACTUATOR, s.mj_actuator)
            servos[s.servo_id] = _Servo(
                index=index,
                servo_id=s.servo_id,
                joint=s.joint,
                actuator=a,
                qpos_adr=int(self.model.jnt_qposadr[j]),
                dof_adr=int(self.model.jnt_dofadr[j]),
                lower=s.lower_rad,
                upper=s.upper_rad,
                max_speed=s.model.no_load_speed_rad_s,
                stall_torque=s.model.stall_torque_nm,
                gainprm=self.model.actuator_gainprm[a].copy(),
                biasprm=self.model.actuator_biasprm[a].copy(),
            )
        return servos

    def _geom_mug_index(self) -> np.ndarray:
        """For every geom, the index of the mug it belongs to, or -1."""
        index = np.full(self.model.ngeom, -1, dtype=np.int64)
        body_to_mug = {b: i for i, b in enumerate(self._mug_body.values())}
        for g in range(self.model.ngeom):
            index[g] = body_to_mug.get(int(self.model.geom_bodyid[g]), -1)
        return index

    def _geom_gripper_mask(self) -> np.ndarray:
        """Geoms of the gripper (palm, thumb, finger, pads): their touch on a mug is a gripper contact."""
        bodies = {int(self.model.geom_bodyid[self._fsr_pad]), int(self.model.geom_bodyid[self._finger_pad])}
        return np.isin(self.model.geom_bodyid, sorted(bodies))

    def _watched_pair_table(self) -> np.ndarray:
        """For every geom pair, whether a contact between them is watched: two different mugs, or a mug
        and the gripper (symmetric, so a contact's geoms index it in either order)."""
        m = self.geom_mug
        mug = m >= 0
        two_mugs = mug[:, None] & mug[None, :] & (m[:, None] != m[None, :])
        mug_gripper = mug[:, None] & self.geom_gripper[None, :]
        return np.asarray(two_mugs | mug_gripper | mug_gripper.T)

    def _settle_at_start(self, pose: Mapping[str, float]) -> None:
        """Put the arm in ``pose``, hold it there and let the mugs settle before anyone looks."""
        unknown = set(pose) - {s.joint for s in self._servos.values()}
        if unknown:
            raise ValueError(f"initial pose names unknown joints {sorted(unknown)}")
        for s in self._servos.values():
            self.data.qpos[s.qpos_adr] = min(max(pose.get(s.joint, 0.0), s.lower), s.upper)
        mujoco.mj_forward(self.model, self.data)
        self._setpoint = self.data.qpos[self._qpos_adr].tolist()
        self._goal = list(self._setpoint)
        self.data.ctrl[self._ctrl_index] = self._setpoint
        self._advance(0.3)
        self._publish_present()
        self.data.time = 0.0
        self._steps = 0
        self._next_monitor = 0.0

    # --------------------------------------------------------------------------------- the servo plant

    def set_goal(self, servo_id: int, position_rad: float, speed_rad_s: float) -> None:
        """A new goal position and moving speed for one servo (``speed_rad_s`` <= 0: as fast as it can).

        Lock-free (two attribute writes the physics thread reads each step): the bus simulator must never
        wait for a batch of physics steps, or the driver sees a servo that does not answer. The goal and
        speed a servo already has (half the goals a job streams) change nothing: a set-point at its goal
        stays settled, and MuJoCo goes on stepping in runs."""
        s = self._servo(servo_id)
        speed = float(s.max_speed if speed_rad_s <= 0.0 else min(speed_rad_s, s.max_speed))
        goal = float(min(max(position_rad, s.lower), s.upper))
        i = s.index
        if goal == self._goal[i] and speed == self._speed[i]:
            return
        self._speed[i] = speed
        self._goal[i] = goal
        self._goal_gen += 1

    def present(self, servo_id: int) -> tuple[float, float, float]:
        """Present position (rad), velocity (rad/s) and load (signed fraction of the stall torque), as of
        the last physics step. Lock-free, like ``set_goal``, while the world steps in its own thread; stepped
        by a clock or ``step_for``, the first read after a batch of steps takes the snapshot (under the lock,
        which nobody else holds then). Once the physics died, ``SimWorldStopped``: its last state is not a
        reading."""
        if self._failure is not None:
            self.check_alive()
        if self._present_due:
            with self.lock:
                if self._present_due:
                    self._publish_present()
        return self._present[self._servo(servo_id).index]

    def set_torque(self, servo_id: int, on: bool) -> None:
        """Torque on holds the present position; torque off lets the joint hang on its gearbox friction."""
        s = self._servo(servo_id)
        with self.lock:
            if on and not s.torque_on:
                held = float(self.data.qpos[s.qpos_adr])
                self._setpoint[s.index] = self._goal[s.index] = self._ctrl[s.actuator] = held
                self._goal_gen += 1
                self.model.actuator_gainprm[s.actuator] = s.gainprm
                self.model.actuator_biasprm[s.actuator] = s.biasprm
            elif not on and s.torque_on:
                self.model.actuator_gainprm[s.actuator] = 0.0
                self.model.actuator_biasprm[s.actuator] = 0.0
            s.torque_on = on

    def _servo(self, servo_id: int) -> _Servo:
        try:
            return self._servos[servo_id]
        except KeyError:
            known = ", ".join(str(i) for i in sorted(self._servos))
            raise KeyError(f"no servo with id {servo_id} in the simulated arm (ids: {known})") from None

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._servos))

    # --------------------------------------------------------------------------------------- sensors

    def gripper_force_n(self) -> float:
        """Normal force on the FSR pad from mugs, as of the last monitor tick (thread-safe, never blocks)."""
        return self._force_n

    def time(self) -> float:
        """Simulated seconds since the world was built (after the initial settling)."""
        return float(self.data.time)

    @property
    def held_mug(self) -> str | None:
        """The mug welded to the gripper by a confirmed grasp, if any."""
        return self._held

    def tcp_position(self) -> tuple[float, float, float]:
        with self.lock:
            p = self.data.site_xpos[self._tcp_site]
            return float(p[0]), float(p[1]), float(p[2])

    def mug_truths(self) -> dict[str, MugTruth]:
        """True mug poses (tests and benchmarks only)."""
        out: dict[str, MugTruth] = {}
        with self.lock:
            for mug, body in self._mug_body.items():
                pos = self.data.xpos[body]
                quat = self.data.xquat[body]
                axis_z = float(self.data.xmat[body][8])
                vel = np.zeros(6)
                mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, body, vel, 0)
                out[mug] = MugTruth(
                    mug,
                    (float(pos[0]), float(pos[1]), float(pos[2])),
                    (float(quat[0]), float(quat[1]), float(quat[2]), float(quat[3])),
                    axis_z,
                    held=mug == self._held,
                    speed_m_s=float(np.linalg.norm(vel[3:])),
                )
        return out

    def add_contact_listener(self, listener: ContactListener) -> None:
        """Call ``listener(world, t, contacts)`` on every monitor tick, from the physics thread, with the lock
        held: mug-mug and gripper-mug contacts, except the gripper's on the mug it has held since the last
        tick (the grasp itself, never a collision). It must be quick and must not block."""
        self._listeners.append(listener)

    # ------------------------------------------------------------------------------------ fault injection

    def slip(self) -> str | None:
        """Make the held mug slip out of the gripper: drop the weld and the pads' grip until the jaw opens.

        Returns the mug that slipped (None when nothing was held). Used by fault-injection tests.
        """
        with self.lock:
            mug = self._held
            if mug is None:
                return None
            self._release(reason="injected_slip")
            self._slipping.add(mug)
            # A higher priority makes the gripper's (now slick) friction win over the mug's in every contact.
            self.model.geom_friction[self._gripper_geoms, 0] = 0.02
            self.model.geom_priority[self._gripper_geoms] = 1
            return mug

    def hold(self, held: HeldMug) -> None:
        """Put ``held`` in the gripper as a confirmed grasp holds it: the body where it is said to be, the jaw
        closed on it, welded (a re-simulation starting with a mug in the gripper). Before the world is
        stepped by anything else, or with ``paused``."""
        with self.lock:
            body = self._mug_body.get(held.mug_id)
            if body is None:
                raise ValueError(f"mug {held.mug_id} is not in the world")
            joint = int(self.model.body_jntadr[body])
            adr = int(self.model.jnt_qposadr[joint])
            dof = int(self.model.jnt_dofadr[joint])
            self.data.qpos[adr : adr + 3] = held.bottom_m
            self.data.qpos[adr + 3 : adr + 7] = _axis_quat(held.axis, held.yaw_rad)
            self.data.qvel[dof : dof + 6] = 0.0
            jaw = self._gripper_servo
            try:
                angle = self.arm.gripper.angle_for_aperture(held.aperture_m)
            except ValueError:
                angle = jaw.upper
            angle = min(max(angle, jaw.lower), jaw.upper)
            self.data.qpos[jaw.qpos_adr] = angle
            self.data.qvel[jaw.dof_adr] = 0.0
            self._setpoint[jaw.index] = self._goal[jaw.index] = angle
            self.data.ctrl[self._ctrl_index] = self._setpoint
            self._goal_gen += 1
            mujoco.mj_forward(self.model, self.data)
            self._force_n = held.force_n
            self._weld_mug(held.mug_id, self.arm.gripper.aperture_m(angle))
            self._publish_present()
        log.info("simworld_mug_held", mug_id=held.mug_id)

    def move_mug(self, mug: str, dx_m: float, dy_m: float) -> None:
        """Shift a mug that stands free (not held) by ``dx_m``, ``dy_m``, at rest: someone moved it on the
        counter. ValueError for an unknown or held mug."""
        with self.lock:
            body = self._mug_body.get(mug)
            if body is None or mug == self._held:
                raise ValueError(f"mug {mug} is not standing free in the world")
            joint = int(self.model.body_jntadr[body])
            if joint < 0 or self.model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
                raise ValueError(f"mug {mug} has no free joint to move it by")
            adr = int(self.model.jnt_qposadr[joint])
            dof = int(self.model.jnt_dofadr[joint])
            self.data.qpos[adr] += dx_m
            self.data.qpos[adr + 1] += dy_m
            self.data.qvel[dof : dof + 6] = 0.0
            mujoco.mj_forward(self.model, self.data)
        log.info("simworld_mug_moved", mug_id=mug, dx_m=dx_m, dy_m=dy_m)

    # ------------------------------------------------------------------------------------------ stepping

    def attach(self, clock: SteppedClock) -> None:
        """Step in lockstep with ``clock`` from now on: world time 0 is the clock's time now."""
        if self._thread is not None or self._detach is not None:
            raise RuntimeError("the world is already running; attach() it once, instead of start()")
        self._epoch = clock.monotonic() - self.time()
        self._detach = clock.add_stepper(self._step_to_clock)
        log.info("simworld_attached", timestep_s=self.physics.timestep_s, mugs=len(self.mug_ids))

    def start(self) -> None:
        """Step in a background thread at real time × ``speed``."""
        if self._detach is not None:
            raise RuntimeError("the world is stepped by a clock; it cannot also start() its own thread")
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="simworld", daemon=True)
        self._thread.start()
        log.info(
            "simworld_started", speed=self.speed, timestep_s=self.physics.timestep_s, mugs=len(self.mug_ids)
        )

    def stop(self) -> None:
        """Stop stepping (the thread, or the clock's stepping)."""
        detach, self._detach = self._detach, None
        if detach is not None:
            detach()
            log.info(
                "simworld_stopped", t=round(self.time(), 3), wall_stepping_s=round(self.wall_stepping_s, 3)
            )
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._stop.set()
        thread.join(timeout=5.0)
        log.info("simworld_stopped", t=round(self.time(), 3), wall_stepping_s=round(self.wall_stepping_s, 3))

    def __enter__(self) -> SimWorld:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def check_alive(self) -> None:
        """Raise ``SimWorldStopped`` when the physics died (diverged) or is not being stepped."""
        if self._failure is not None:
            raise SimWorldStopped(f"the physics died: {self._failure}") from self._failure
        if self._detach is not None:
            return
        if self._thread is None or not self._thread.is_alive():
            raise SimWorldStopped("the physics thread is not running; call SimWorld.start()")

    def step_for(self, seconds: float) -> None:
        """Advance the simulation synchronously (only while neither a thread nor a clock steps it)."""
        if self._thread is not None or self._detach is not None:
            raise RuntimeError("step_for() while the world is being stepped; stop() it first")
        with self.lock:
            self._advance(seconds)

    @contextmanager
    def paused(self) -> Iterator[None]:
        """Hold the physics still (e.g. to render or inspect a consistent state)."""
        with self.lock:
            yield

    def _step_to_clock(self, t: float) -> None:
        """The clock's stepper: whole physics steps up to world time ``t - epoch``. A divergence stops the
        world as it stops the thread (``check_alive`` raises); the clock goes on."""
        if self._failure is not None:
            return
        steps = math.floor((t - self._epoch) / self.physics.timestep_s + 1e-6) - self._steps
        if steps <= 0:
            return
        started = time.perf_counter()
        try:
            with self.lock:
                self._run_steps(steps)
        except Exception as e:  # as in the thread: the world stops, the clock (and the daemon) go on
            self._failure = e
            log.error("simworld_died", error=str(e), t=round(self.time(), 3))
        self.wall_stepping_s += time.perf_counter() - started

    def _run(self) -> None:
        wall0 = time.monotonic()
        sim0 = self.time()
        behind_logged = False
        try:
            while not self._stop.is_set():
                target = sim0 + (time.monotonic() - wall0) * self.speed
                lag = target - self.time()
                if lag <= 0.0:
                    time.sleep(min(0.002, -lag / self.speed + 0.0005))
                    continue
                started = time.perf_counter()
                with self.lock:
                    self._advance(min(lag, self.physics.max_batch_s))
                self.wall_stepping_s += time.perf_counter() - started
                if lag > 0.5 and not behind_logged:
                    log.warning("simworld_behind_real_time", lag_s=round(lag, 3), speed=self.speed)
                    behind_logged = True
                elif lag < 0.05 and behind_logged:
                    log.info("simworld_caught_up", speed=self.speed)
                    behind_logged = False
                time.sleep(0)  # let the servo simulator and the event loop have the GIL
        except BaseException as e:
            self._failure = e
            log.error("simworld_died", error=str(e), t=round(self.time(), 3))

    def _advance(self, seconds: float) -> None:
        self._run_steps(max(1, round(seconds / self.physics.timestep_s)))

    def _run_steps(self, steps: int) -> None:
        model, data = self.model, self.data
        dt = self.physics.timestep_s
        left = steps
        while left > 0:
            if self._settled_gen != self._goal_gen:
                # A set-point is walking: one step at a time, each with its own control.
                self._drive_servos(dt)
                n = 1
            else:
                # The controls stay as they are: MuJoCo steps on its own until the monitor is due.
                n = self._steps_until_monitor(left, dt)
            mujoco.mj_step(model, data, n)
            self._steps += n
            left -= n
            if data.time >= self._next_monitor:
                self._next_monitor = data.time + self.physics.monitor_period_s
                self._monitor()
        # A diverged state is never published: the world stops before a reader could take it.
        if _count_nonzero(self._bad_state_counts) or not math.isfinite(_sum(data.qpos)):
            raise SimModelError(f"the simulation diverged by t={self.time():.3f} s ({self._what_diverged()})")
        # Once per batch: stepped by a clock, nobody reads between the steps of a batch (they run on the
        # reader's thread), so the snapshot is taken when it is first read (most batches end at an FSR
        # sample, with no servo read before the next one); in the world's own thread a batch is at most
        # ``max_batch_s`` of real time and the snapshot is taken at once, so a reader never waits for a batch.
        if self._thread is None:
            self._present_due = True
        else:
            self._publish_present()

    def _what_diverged(self) -> str:
        """What MuJoCo found bad (its warnings), or the positions that are not finite (a sum is NaN or
        infinite when any term is)."""
        kinds = ("positions", "velocities", "accelerations")
        flagged = [k for k, n in zip(kinds, self._bad_state_counts, strict=True) if n]
        if flagged:
            listed = " and ".join(filter(None, (", ".join(flagged[:-1]), flagged[-1])))
            return f"NaN, infinite or huge {listed}"
        return "non-finite positions"

    def _steps_until_monitor(self, most: int, dt: float) -> int:
        """How many steps (1 to ``most``) take the world's time to the next monitor tick. Worked out with
        the addition MuJoCo makes each step (``time += timestep``), so the tick falls on the same step as
        when the time is looked at after every step."""
        t = float(self.data.time)
        due = self._next_monitor
        n = 1
        t += dt
        while n < most and t < due:
            t += dt
            n += 1
        return n

    def _publish_present(self) -> None:
        """Swap in a fresh snapshot of every servo's state (one reference assignment: atomic for readers)."""
        self._present_due = False
        d = self.data
        loads = [
            min(max(force / stall, -1.0), 1.0)
            for force, stall in zip(d.actuator_force[self._ctrl_index].tolist(), self._stall, strict=True)
        ]
        self._present = tuple(
            zip(d.qpos[self._qpos_index].tolist(), d.qvel[self._qvel_index].tolist(), loads, strict=True)
        )

    def _drive_servos(self, dt: float) -> None:
        """Walk each set-point towards its goal at the commanded speed, as the servo firmware does.

        Only a set-point that moves is written to its control (one element each, no list to convert): every
        other control holds its set-point already, since whatever sets one (``set_torque``, ``hold``, the
        settling) writes it too."""
        gen = self._goal_gen
        if self._settled_gen == gen:
            return  # every set-point is at its goal: the controls stay as they are
        setpoint, goal, speed = self._setpoint, self._goal, self._speed
        ctrl, actuator = self._ctrl, self._actuator_list
        moved = False
        for i, s in enumerate(setpoint):
            g = goal[i]
            if s == g:
                continue
            step = speed[i] * dt
            delta = g - s
            if delta > step:
                delta = step
            elif delta < -step:
                delta = -step
            if delta != 0.0:
                s += delta
                setpoint[i] = s
                ctrl[actuator[i]] = s
                moved = True
        if not moved:
            self._settled_gen = gen

    # ------------------------------------------------------------------------- grasp and contact monitor

    def _monitor(self) -> None:
        grip = self._scan_contacts()
        now = self.time()
        if self._held is None:
            self._force_n = grip.pad_force_n
            if grip is not _NO_CONTACTS:  # without a contact on the pads nothing can be welded
                self._weld_if_grasped(grip)
        else:
            self._watch_grasp(grip, now)
        if self._slipping:
            self._end_slip_when_opened()
        for listener in self._listeners:
            listener(self, now, grip.contacts)

    def _jaw_aperture_m(self) -> float:
        return self.arm.gripper.aperture_m(float(self.data.qpos[self._gripper_servo.qpos_adr]))

    def _weld_if_grasped(self, grip: _GripContacts) -> None:
        """Weld the mug squeezed between both pads hard enough, resting on nothing else (nothing held)."""
        between = grip.thumb_mugs & grip.finger_mugs
        if (
            grip.pad_force_n >= self.physics.weld_force_n
            and len(between) == 1
            and grip.support_force_n <= 0.1 * self.physics.support_force_n
        ):
            mug = self.mug_ids[next(iter(between))]
            if mug not in self._slipping:
                self._weld_mug(mug, self._jaw_aperture_m())

    def _watch_grasp(self, grip: _GripContacts, now: float) -> None:
        """The held mug's force reading, and the weld let go when it is supported, the jaw opens or the
        force stays low."""
        aperture = self._jaw_aperture_m()
        self._force_n = self._squeeze_n(aperture)
        if grip.support_force_n > self.physics.support_force_n:
            # Pressed onto something: from here friction alone decides, so the mug can slide in the grasp.
            self._release(reason="supported")
            self._force_n = self._pad_force_n()
            return
        opened = aperture >= self._held_aperture_m + self.physics.release_opening_m
        if self._force_n < self.physics.release_force_n:
            self._low_force_since = self._low_force_since if self._low_force_since is not None else now
        else:
            self._low_force_since = None
        since = self._low_force_since
        weak = since is not None and now - since >= self.physics.release_after_s
        if opened or weak:
            self._release(reason="opened" if opened else "force_lost")

    def _end_slip_when_opened(self) -> None:
        """Give the pads their grip back once the jaw is commanded open past the slipped grasp."""
        jaw = self._gripper_servo
        if self.arm.gripper.aperture_m(float(self._goal[jaw.index])) > self._held_aperture_m + 0.005:
            self._slipping.clear()
            self.model.geom_friction[self._gripper_geoms] = self._gripper_friction
            self.model.geom_priority[self._gripper_geoms] = 0

    def _squeeze_n(self, aperture_m: float) -> float:
        """What the FSR reads while the weld carries the mug.

        The weld stands in for friction, and it also takes up part of the squeeze, so the contact forces
        then swing with every jolt of the arm (a dip to zero would look like a drop). The pads are treated as
        a linear spring instead: the force at the confirmed grasp, falling to zero as the jaw opens by
        ``release_opening_m`` and rising as it closes further."""
        opening = (aperture_m - self._held_aperture_m) / self.physics.release_opening_m
        return self._held_force_n * min(max(1.0 - opening, 0.0), 2.0)

    def _scan_contacts(self) -> _GripContacts:
        """Mug-mug and gripper-mug contacts of this instant, and what they mean for the grasp.

        Vectorised over MuJoCo's contact arrays: each contact's geom pair becomes one key (``geom1 * ngeom +
        geom2``, a single matrix product), and every question asked of the contacts is one lookup of the
        keys in a precomputed flat pair table: whether the pair is watched, and whether it pushes on a given
        mug from anything but the gripper (the support force). A contact's normal force is read straight
        from the constraint forces (with the elliptic friction cone the cell uses, ``mj_contactForce``
        copies exactly these numbers). Python touches only the contacts that may be collisions or grasps;
        while a mug is held (half of all monitor ticks in a job), the gripper's own contacts on it are
        masked out by the table and never reach a listener (they are never collisions), and the pad force
        is the squeeze model's, so the pads' sum is not taken (``_pad_force_n`` works it out when the grasp
        lets go)."""
        data = self.data
        if data.ncon == 0:
            return _NO_CONTACTS
        contact = data.contact
        geom = contact.geom
        pairs = geom @ self._pair_key
        held = self._held
        if held is None:
            looked_at = self._watched_flat.take(pairs).nonzero()[0]
            if looked_at.size == 0:
                return _NO_CONTACTS
        else:
            codes = self._holding_table(self._mug_index[held]).take(pairs)
            if not _count_nonzero(codes):
                return _NO_CONTACTS  # the grip alone (a carry): nothing to report, nothing under the mug
            looked_at = (codes & _WATCHED).nonzero()[0]
        grip = _GripContacts()
        efc_address = contact.efc_address
        efc_force = data.efc_force
        if looked_at.size:
            self._read_contacts(grip, geom, looked_at, efc_address, efc_force, contact.pos)
        # What else pushes on the mug in the gripper (or about to be): the table, the tray, another mug.
        if held is None:
            candidates = grip.thumb_mugs & grip.finger_mugs
            if not candidates:
                return grip
            first, *rest = candidates
            mine = self._supporting(first).take(pairs)
            for c in rest:
                mine |= self._supporting(c).take(pairs)
        else:
            mine = codes >= _SUPPORTING
        for address in efc_address[mine].tolist():
            grip.support_force_n += float(efc_force[address]) if address >= 0 else 0.0
        return grip

    def _holding_table(self, mug: int) -> np.ndarray:
        """The flat pair table while mug number ``mug`` is held, both questions in one lookup: ``_WATCHED``
        for the watched pairs without the gripper's pairs with that mug (the grasp itself), plus
        ``_SUPPORTING`` for the pairs that push on it from anything but the gripper; worked out the first
        time that mug is held."""
        table = self._holding_tables.get(mug)
        if table is None:
            held = self.geom_mug == mug
            grasp = held[:, None] & self.geom_gripper[None, :]
            watched = (self._watched_pairs & ~(grasp | grasp.T)).ravel()
            supporting = self._supporting(mug)
            table = watched.astype(np.uint8) * _WATCHED | supporting.astype(np.uint8) * _SUPPORTING
            self._holding_tables[mug] = table
        return table

    def _supporting(self, mug: int) -> np.ndarray:
        """The flat pair table of the contacts that push on mug number ``mug`` from anything but the
        gripper (one geom the mug's, the other not the gripper's, in either order), worked out the first
        time it is asked for."""
        table = self._support_tables.get(mug)
        if table is None:
            own = self.geom_mug == mug
            not_gripper = ~self.geom_gripper
            one_way = own[:, None] & not_gripper[None, :]
            table = self._support_tables[mug] = (one_way | one_way.T).ravel()
        return table

    def _read_contacts(
        self,
        grip: _GripContacts,
        geom: np.ndarray,
        looked_at: np.ndarray,
        efc_address: np.ndarray,
        efc_force: np.ndarray,
        pos: np.ndarray,
    ) -> None:
        """Add the contacts ``looked_at`` (indices into MuJoCo's contact arrays) to ``grip``: the pad force,
        which mugs touch the thumb and the finger, and a sample of each for the listeners."""
        geom_mug, body = self._geom_mug_list, self._geom_body_list
        fsr_pad, tool_body, finger_body = self._fsr_pad, self._tool_body, self._finger_body
        for (a, b), address, p in zip(
            geom[looked_at].tolist(),
            efc_address[looked_at].tolist(),
            pos[looked_at].tolist(),
            strict=True,
        ):
            force = float(efc_force[address]) if address >= 0 else 0.0
            m1, m2 = geom_mug[a], geom_mug[b]
            other, mug = (b, m1) if m1 >= 0 and m2 < 0 else (a, m2)
            if other == fsr_pad:
                grip.pad_force_n += force
            if body[other] == tool_body and force > 0.0:
                grip.thumb_mugs.add(mug)
            elif body[other] == finger_body and force > 0.0:
                grip.finger_mugs.add(mug)
            grip.contacts.append(ContactSample(a, b, (p[0], p[1], p[2]), force))

    def _pad_force_n(self) -> float:
        """The normal force of every mug on the FSR pad now, summed in MuJoCo's contact order."""
        data = self.data
        if data.ncon == 0:
            return 0.0
        contact = data.contact
        geom = contact.geom
        g1, g2 = geom[:, 0], geom[:, 1]
        fsr = self._fsr_pad
        on_pad = self._watched_pairs[g1, g2] & ((g1 == fsr) | (g2 == fsr))
        force = 0.0
        for address in contact.efc_address[on_pad].tolist():
            force += float(data.efc_force[address]) if address >= 0 else 0.0
        return force

    def _weld_mug(self, mug: str, aperture_m: float) -> None:
        eq = self._weld[mug]
        body = self._mug_body[mug]
        tool = self._tool_body
        inv = np.zeros(4)
        mujoco.mju_negQuat(inv, self.data.xquat[tool])
        rel_pos = np.zeros(3)
        mujoco.mju_rotVecQuat(rel_pos, self.data.xpos[body] - self.data.xpos[tool], inv)
        rel_quat = np.zeros(4)
        mujoco.mju_mulQuat(rel_quat, inv, self.data.xquat[body])
        self.model.eq_data[eq, 0:3] = 0.0
        self.model.eq_data[eq, 3:6] = rel_pos
        self.model.eq_data[eq, 6:10] = rel_quat
        self.model.eq_data[eq, 10] = 1.0
        self.data.eq_active[eq] = 1
        self._held = mug
        self._held_aperture_m = aperture_m
        self._held_force_n = self._force_n
        self._low_force_since = None
        log.debug(
            "simworld_grasp_welded", mug_id=mug, force_n=round(self._force_n, 2), t=round(self.time(), 3)
        )

    def _release(self, *, reason: str) -> None:
        mug = self._held
        if mug is None:
            return
        self.data.eq_active[self._weld[mug]] = 0
        self._held = None
        self._low_force_since = None
        log.debug("simworld_grasp_released", mug_id=mug, reason=reason, t=round(self.time(), 3))


def _log_mujoco_warnings() -> None:
    """Send MuJoCo's warnings (a diverged state, a full contact buffer) to the log, once per process. By
    default MuJoCo prints them and appends them to ``MUJOCO_LOG.TXT`` in the working directory, which for
    a daemon is nobody's and for a test run is the source tree."""
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_mujoco_warning)


def _mujoco_warning(message: str) -> None:
    log.warning("mujoco_warning", message=message)


# ``ndarray.sum`` without its Python wrapper (the divergence check runs after every batch of steps).
_sum = np.add.reduce
# Whether any entry is set, as a count (``ndarray.any`` goes through a Python wrapper; the contact scan asks
# on most ticks of a carry).
_count_nonzero = np.count_nonzero


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as the slice it spans when its entries are consecutive and increasing, else itself."""
    first = int(index[0])
    if np.array_equal(index, np.arange(first, first + len(index))):
        return slice(first, first + len(index))
    return index


def _axis_quat(axis: Sequence[float], yaw_rad: float) -> np.ndarray:
    """The body quaternion (w, x, y, z) that turns the mug's own z onto ``axis`` after turning it by
    ``yaw_rad`` about its own axis."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / (np.linalg.norm(a) or 1.0)
    yaw = np.array([math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)])
    cross = np.cross((0.0, 0.0, 1.0), a)
    sin = float(np.linalg.norm(cross))
    if sin < 1e-9:
        align = np.array([1.0, 0.0, 0.0, 0.0]) if a[2] > 0 else np.array([0.0, 1.0, 0.0, 0.0])
    else:
        angle = math.atan2(sin, float(a[2]))
        k = cross / sin
        align = np.array([math.cos(angle / 2), *(k * math.sin(angle / 2))])
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, align, yaw)
    return out


__all__ = [
    "ARM_PREFIX",
    "MUG_BODY_PREFIX",
    "ContactSample",
    "HeldMug",
    "MugTruth",
    "PhysicsConfig",
    "SimWorld",
]
