"""Re-simulation: the world a recording saw at one moment, and the stand-in cell set to it.

A replay serves the recorded inputs for as long as the daemon does what it did; from the first divergence
or injected fault it goes on in a simulated stand-in cell (``replay.engine``). That cell is set to the
world *the recording saw* at that instant (``world_at``), whatever backend wrote the file:

- **counter mugs** where the camera last saw them: type, pose, handle, upside down or not, by the job's
  own ids (the ``detections`` the job published after each look at the counter); before its first look,
  as that first look found them;
- **mugs on the tray** where the job put them (its ``mug_placed`` events, brim down as every placed mug
  stands); for a job that continued an earlier job's tray, those the header says it carried over (its
  ``job.carried`` tray slots: where the earlier jobs placed them; an older header's scene, else none);
- **the arm** at its last recorded joint angles (``input/joints``);
- **the gripper** holding what the force sensor's holding flag said (``input/holding``), and which mug:
  the job's current mug (``state``). A mug the gripper let go of since the camera last saw it (set down
  in the flip area, dropped) stands where the gripper released it: the grasp point at the joints of
  that moment, turned as the arm turned it between the grasp and the release.

Everything here is a pure function of the recording (and the arm model for the forward kinematics); what
sets a simulated world to it is ``restage``. The world the recording saw is all a replay knows after a
divergence: what follows is model-based (the stand-in's physics, not the robot's).
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Final, Literal

import numpy as np

from planning.arm import ArmModel
from replay.errors import ReplayError
from replay.session import RecordedSession
from sim.kinematic import SimMug
from validation import Invalid, convert
from wire.messages import (
    Command,
    Detections,
    Force,
    Gripper,
    HeaderJob,
    HeaderSceneMug,
    HeaderSlot,
    Holding,
    InputJoints,
    MugPlacedEvent,
    State,
    UnsetType,
    header_part,
)
from wire.schemas import topic_suffix

if TYPE_CHECKING:
    from daemon.backend import Backend
    from daemon.job.context import JobContext
    from description.thesis import MugSpec
    from sim.mujoco.cell import SimCell

Where = Literal["counter", "tray", "gripper"]
# How a mug's place is known: the camera saw it there, the job placed it there, the header of a job that
# continued an earlier tray had it there, the gripper let go of it there, or the gripper holds it.
Source = Literal["seen", "placed", "header", "released", "held"]
# The worlds a replay can re-simulate in.
STAND_INS: Final = ("kinematic", "mujoco")


@dataclass(frozen=True, slots=True)
class WorldMug:
    """One mug of the world the recording saw: the job's id, type and pose (its axis on the surface it
    stands on, world frame, metres)."""

    mug_id: str
    type: str
    x_m: float
    y_m: float
    handle_yaw_rad: float
    upside_down: bool
    where: Where
    source: Source
    at_s: float  # when its place was last known, seconds from the job's start
    # Where its bottom is (the body's origin: on the surface for an upright mug, a height up for one on its
    # brim; anywhere for a held one) and its axis from bottom to brim, for a physics world.
    bottom_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def to_json(self) -> dict[str, object]:
        return {
            "id": self.mug_id,
            "type": self.type,
            "x_m": round(self.x_m, 5),
            "y_m": round(self.y_m, 5),
            "handle_yaw_rad": round(self.handle_yaw_rad, 5),
            "upside_down": self.upside_down,
            "where": self.where,
            "source": self.source,
            "at_s": round(self.at_s, 6),
            "bottom_m": [round(v, 5) for v in self.bottom_m],
            "axis": [round(v, 5) for v in self.axis],
        }


@dataclass(frozen=True, slots=True)
class RecordedWorld:
    """The world a recording saw at ``t_s`` (seconds from the job's start)."""

    t_s: float
    joint_names: tuple[str, ...]
    joints_rad: tuple[float, ...]  # the arm's last recorded joint angles (empty: none recorded yet)
    holding: bool  # the force sensor's holding flag
    force_n: float  # the last recorded pad force
    aperture_m: float | None  # the gripper's last published opening (None: none yet)
    held: str | None  # the job's id of the mug in the gripper
    mugs: tuple[WorldMug, ...]

    def on(self, where: Where) -> tuple[WorldMug, ...]:
        return tuple(m for m in self.mugs if m.where == where)

    def to_json(self) -> dict[str, object]:
        return {
            "t_s": round(self.t_s, 6),
            "joints_rad": [round(v, 6) for v in self.joints_rad],
            "holding": self.holding,
            "force_n": round(self.force_n, 4),
            "aperture_m": None if self.aperture_m is None else round(self.aperture_m, 5),
            "held": self.held,
            "mugs": [m.to_json() for m in self.mugs],
        }

    def describe(self) -> str:
        """One line: what is where."""
        parts = []
        places: tuple[tuple[Where, str], ...] = (("counter", "on the counter"), ("tray", "on the tray"))
        for where, label in places:
            mugs = self.on(where)
            ids = " ".join(m.mug_id for m in mugs)
            parts.append(f"{len(mugs)} {label}" + (f" ({ids})" if ids else ""))
        parts.append(f"{self.held} held" if self.held is not None else "nothing held")
        return ", ".join(parts)


def world_at(session: RecordedSession, t_s: float, *, arm: ArmModel | None = None) -> RecordedWorld:
    """The world ``session`` saw at ``t_s`` seconds from its job's start (see the module's docstring)."""
    arm = arm or ArmModel.load()
    catalogue = session.config.mug_catalogue()
    sizes = {name: (spec.diameter_mm / 1000.0, spec.height_mm / 1000.0) for name, spec in catalogue.items()}
    until_ns = session.start_ns + round(t_s * 1e9)
    mugs: dict[str, WorldMug] = {m.mug_id: m for m in _header_tray(session, sizes)}
    names: tuple[str, ...] = ()
    q: tuple[float, ...] = ()
    holding = False
    force = 0.0
    aperture: float | None = None
    current: str | None = None
    grip: _Grip | None = None  # how the held mug sits in the gripper, since its grasp
    looked = False
    for m in session.read.messages[1:]:
        if m.log_time_ns > until_ns:
            break
        at = (m.log_time_ns - session.start_ns) / 1e9
        suffix = topic_suffix(m.topic)
        # Each message read as its topic's declared one (a malformed one is left out: what it would have
        # said stays as before it); the older recordings' shapes are those (``tests/data``).
        if suffix == "input/joints":
            joints = m.decoded(InputJoints)
            if joints is not None:
                names, q = tuple(joints.names), tuple(float(v) for v in joints.position_rad)
        elif suffix == "input/force":
            read = m.decoded(Force)
            force = _finite(read.force_n, force) if read is not None else force
        elif suffix == "gripper":
            gripper = m.decoded(Gripper)
            if gripper is not None:
                aperture = _finite(gripper.aperture_m, aperture if aperture is not None else 0.0)
        elif suffix == "state":
            state = m.decoded(State)  # (None: a malformed one, which says no mug is being handled)
            named = state.current_mug if state is not None else None
            current = named if isinstance(named, str) and named else None
        elif suffix == "detections":
            seen = m.decoded(Detections)
            if seen is not None:
                looked = True
                mugs = _after_look(mugs, seen, at, keep=current if holding else None, sizes=sizes)
        elif suffix == "events" and (placed := m.decoded(MugPlacedEvent)) is not None:
            mugs = _placed(mugs, placed, at, sizes=sizes)
        elif suffix == "input/holding":
            says = m.decoded(Holding)
            now = says is not None and says.holding
            mug = mugs.get(current) if current is not None and len(q) == arm.dof else None
            if mug is not None and now and not holding:  # a grasp: the mug moves with the gripper from here
                grip = _Grip.of(mug, *arm.fk(q))
            elif mug is not None and holding and not now:  # let go of: it stands where it was released
                if mug.where != "tray":
                    mugs[mug.mug_id] = _in_gripper(mug, arm, q, grip, sizes, at, "released")
                grip = None
            holding = now
    if not any(m.where == "counter" for m in mugs.values()) and not looked:
        # Before the job's first look the counter is as that look found it (nothing took a mug before it).
        first = next((d for d in _looks(session) if d is not None), None)
        if first is not None:
            mugs = _after_look(mugs, first, 0.0, keep=None, sizes=sizes)
    held = current if holding and current is not None and current in mugs else None
    if held is not None and len(q) == arm.dof:
        mugs[held] = _in_gripper(mugs[held], arm, q, grip, sizes, t_s, "held")
    return RecordedWorld(
        t_s=t_s,
        joint_names=names,
        joints_rad=q,
        holding=holding,
        force_n=force,
        aperture_m=aperture,
        held=held,
        mugs=tuple(sorted(mugs.values(), key=lambda w: (w.where, w.mug_id))),
    )


def _header_tray(session: RecordedSession, sizes: Mapping[str, tuple[float, float]]) -> list[WorldMug]:
    """The mugs an earlier job left on the tray, where the header says they stand.

    A job that went on with an earlier job's tray has it in its header's ``job.carried``: the tray's slots
    as the earlier jobs placed them, by the job's ids (each mug stands brim down on its slot's axis, its
    handle where the slot says, else along +x, +y for a rotated slot), whatever backend wrote it. An older
    recording without ``job.carried`` has only its scene: a simulated scene that says where each mug is,
    by the simulated world's ids (one the job uses for another mug is renamed ``earlier-<id>``); the tray
    is empty otherwise."""
    carried = header_part(session.job, HeaderJob).carried
    # (Its slots are ``planning.interfaces.TraySlot`` as JSON, each read through ``HeaderSlot``.)
    slots = None if isinstance(carried, UnsetType) else carried.get("on_tray")
    if isinstance(slots, list):
        return [
            _carried_mug(header_part(slot, HeaderSlot), sizes) for slot in slots if isinstance(slot, Mapping)
        ]
    taken = {_text(d.id) for look in _looks(session) if look is not None for d in look.mugs}
    out = []
    # An older recording's scene mugs: the simulated world's own table of each (``HeaderSceneMug``), not in
    # the header view ``HeaderScene`` (one odd mug would empty the whole view).
    scene_mugs = session.scene.get("mugs")
    for m in (header_part(d, HeaderSceneMug) for d in (scene_mugs if isinstance(scene_mugs, list) else [])):
        if m.where == "tray":
            mug_id, kind = _text(m.id), _text(m.type)
            x, y = _finite(m.x_m), _finite(m.y_m)
            upside_down = True if isinstance(m.upside_down, UnsetType) else m.upside_down
            out.append(
                WorldMug(
                    mug_id=f"earlier-{mug_id}" if mug_id in taken else mug_id,
                    type=kind,
                    x_m=x,
                    y_m=y,
                    handle_yaw_rad=_finite(m.handle_yaw_rad),
                    upside_down=upside_down,
                    where="tray",
                    source="header",
                    at_s=0.0,
                    **_standing(x, y, upside_down, sizes.get(kind, (0.0, 0.0))[1]),
                )
            )
    return out


def _looks(session: RecordedSession) -> list[Detections | None]:
    """Every look at the counter the job published (``detections``), in order; None for a malformed one."""
    return [m.decoded(Detections) for m in session.read.messages if topic_suffix(m.topic) == "detections"]


def _carried_mug(slot: HeaderSlot, sizes: Mapping[str, tuple[float, float]]) -> WorldMug:
    """The mug on one of the header's carried tray slots."""
    kind, x, y = _text(slot.type), _finite(slot.x_m), _finite(slot.y_m)
    handle = slot.handle_yaw_rad
    if isinstance(handle, int | float) and math.isfinite(handle):
        yaw = float(handle)
    else:
        yaw = math.pi / 2.0 if slot.rotated is True else 0.0
    return WorldMug(
        mug_id=_text(slot.mug_id),
        type=kind,
        x_m=x,
        y_m=y,
        handle_yaw_rad=yaw,
        upside_down=True,  # every mug goes into the dishwasher's tray brim down
        where="tray",
        source="header",
        at_s=0.0,
        **_standing(x, y, True, sizes.get(kind, (0.0, 0.0))[1]),
    )


def _after_look(
    mugs: Mapping[str, WorldMug],
    detections: Detections,
    at: float,
    *,
    keep: str | None,
    sizes: Mapping[str, tuple[float, float]],
) -> dict[str, WorldMug]:
    """The mugs after a look at the counter: the counter is what the camera saw (by the job's ids); the
    tray, and the mug in the gripper, stay as they were."""
    out = {k: m for k, m in mugs.items() if m.where != "counter" or k == keep}
    for d in detections.mugs:
        mug_id = _text(d.id)
        known = out.get(mug_id)
        if not mug_id or (known is not None and known.where != "counter"):
            continue
        kind, x, y, upside_down = d.type, _finite(d.x_m), _finite(d.y_m), d.upside_down is True
        out[mug_id] = WorldMug(
            mug_id=mug_id,
            type=kind,
            x_m=x,
            y_m=y,
            handle_yaw_rad=_finite(d.handle_yaw_rad),
            upside_down=upside_down,
            where="counter",
            source="seen",
            at_s=at,
            **_standing(x, y, upside_down, sizes.get(kind, (0.0, 0.0))[1]),
        )
    return out


def _standing(
    x: float, y: float, upside_down: bool, height_m: float
) -> dict[str, tuple[float, float, float]]:
    """The bottom and axis of a mug standing at (x, y) on the counter, upright or on its brim."""
    if upside_down:
        return {"bottom_m": (x, y, height_m), "axis": (0.0, 0.0, -1.0)}
    return {"bottom_m": (x, y, 0.0), "axis": (0.0, 0.0, 1.0)}


@dataclass(frozen=True, slots=True)
class _Grip:
    """How a grasped mug sits in the gripper: its bottom and axis in the grasp frame."""

    bottom: np.ndarray
    axis: np.ndarray

    @classmethod
    def of(cls, mug: WorldMug, p: np.ndarray, r: np.ndarray) -> _Grip:
        return cls(r.T @ (np.asarray(mug.bottom_m) - p), r.T @ np.asarray(mug.axis))


def _placed(
    mugs: Mapping[str, WorldMug],
    event: MugPlacedEvent,
    at: float,
    *,
    sizes: Mapping[str, tuple[float, float]],
) -> dict[str, WorldMug]:
    """The mugs after the job placed one on the tray (brim down, bottom and axis as it stands on the
    surface: a physics world puts it on the tray's)."""
    out = dict(mugs)
    mug_id = event.mug_id
    known = out.get(mug_id)
    kind = known.type if known is not None else ""
    x, y = _finite(event.x_m), _finite(event.y_m)
    out[mug_id] = WorldMug(
        mug_id=mug_id,
        type=kind,
        x_m=x,
        y_m=y,
        handle_yaw_rad=_finite(event.handle_yaw_rad, known.handle_yaw_rad if known is not None else 0.0),
        upside_down=True,  # every mug goes into the dishwasher's tray brim down
        where="tray",
        source="placed",
        at_s=at,
        **_standing(x, y, True, sizes.get(kind, (0.0, 0.0))[1]),
    )
    return out


def _in_gripper(
    mug: WorldMug,
    arm: ArmModel,
    q: Sequence[float],
    grip: _Grip | None,
    sizes: Mapping[str, tuple[float, float]],
    at: float,
    source: Source,
) -> WorldMug:
    """``mug`` as the gripper at joints ``q`` has it: moved and turned with the gripper since its grasp
    (without a recorded grasp: its axis at the grasp point, a radius less the thumb's width to the side);
    in the gripper (``held``), or let go of there (standing where it was released)."""
    p, r = arm.fk(q)
    diameter, height = sizes.get(mug.type, (0.08, 0.1))
    if grip is None:
        centre = p + r[:, 1] * (diameter / 2.0 - arm.gripper.thumb_width_m)
        bottom, axis = np.array([centre[0], centre[1], 0.0]), np.asarray(mug.axis)
    else:
        bottom, axis = p + r @ grip.bottom, r @ grip.axis
    upside_down = bool(axis[2] < 0.0)
    # The axis's foot on the surface below: the bottom, or a mug's height along the axis for one on its brim.
    foot = bottom + axis * height if upside_down else bottom
    held = source == "held"
    return replace(
        mug,
        x_m=float(foot[0]),
        y_m=float(foot[1]),
        upside_down=upside_down,
        where="gripper" if held else "counter",
        source=source,
        at_s=at,
        bottom_m=_triple(bottom)
        if held
        else _standing(float(foot[0]), float(foot[1]), upside_down, height)["bottom_m"],
        axis=_triple(axis) if held else (0.0, 0.0, -1.0 if upside_down else 1.0),
    )


def _triple(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _finite(value: float | UnsetType | None, default: float = 0.0) -> float:
    """A read number, or ``default`` when the message leaves it out (or it is not finite)."""
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else default


def _text(value: str | UnsetType) -> str:
    return "" if isinstance(value, UnsetType) else value


# --- the stand-in cell -------------------------------------------------------------------------------------


def restage(backend: Backend, world: RecordedWorld, catalogue: Mapping[str, MugSpec]) -> str:
    """Set the simulated cell behind ``backend`` to ``world`` (mug types from ``catalogue``); its name
    (``kinematic``, ``mujoco``). ``TypeError`` for a backend without a simulated world."""
    from daemon.sim_backend import KinematicCounter, MujocoCounter

    counter = backend.counter
    if isinstance(counter, KinematicCounter):
        kinematic = counter.cell.world
        kinematic.restage(
            [
                SimMug(m.mug_id, m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, m.where)
                for m in world.mugs
                if m.where != "gripper"
            ],
            q=world.joints_rad or None,
            held=_held_sim_mug(world),
            force_n=world.force_n,
        )
        if world.held is None and world.aperture_m is not None:
            kinematic.aperture_m = world.aperture_m
        counter.cell.plant.follow_world()  # the servo simulators stand where the world now is
        return "kinematic"
    if isinstance(counter, MujocoCounter):
        _restage_mujoco(counter.cell, world, catalogue)
        return "mujoco"
    raise TypeError(f"the {backend.name} backend has no simulated world to re-simulate in")


def _restage_mujoco(cell: SimCell, world: RecordedWorld, catalogue: Mapping[str, MugSpec]) -> None:
    from description.cell import SceneMug
    from sim.mujoco.world import HeldMug

    gripper = cell.world.arm.gripper
    known = [m for m in world.mugs if m.type in catalogue]
    scene = [
        SceneMug(m.mug_id, catalogue[m.type], m.x_m, m.y_m, m.handle_yaw_rad, m.upside_down) for m in known
    ]
    pose = dict(zip(world.joint_names, world.joints_rad, strict=False))
    held: HeldMug | None = None
    for m in known:
        if m.where != "gripper":
            continue
        diameter = catalogue[m.type].diameter_mm / 1000.0
        aperture = world.aperture_m if world.aperture_m is not None else diameter
        held = HeldMug(m.mug_id, m.bottom_m, m.axis, m.handle_yaw_rad, min(aperture, diameter), world.force_n)
    if held is None and world.aperture_m is not None:
        with contextlib.suppress(ValueError):
            pose["gripper"] = gripper.angle_for_aperture(world.aperture_m)
    cell.restage(scene, pose=pose, held=held)


def _held_sim_mug(world: RecordedWorld) -> SimMug | None:
    for m in world.on("gripper"):
        return SimMug(m.mug_id, m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, "gripper")
    return None


def cell_truth(backend: Backend) -> dict[str, tuple[str, float, float]]:
    """Where the simulated cell has its mugs standing free now (id: type, x, y): for the cross-check of a
    simulated recording's header scene against what the recording saw."""
    from daemon.sim_backend import KinematicCounter, MujocoCounter

    counter = backend.counter
    if isinstance(counter, KinematicCounter):
        return {
            m.mug_id: (m.type, m.x_m, m.y_m) for m in counter.cell.world.mugs.values() if m.where != "gripper"
        }
    if isinstance(counter, MujocoCounter):
        types = {m.mug_id: m.spec.name for m in counter.cell.mugs}
        return {
            t.mug_id: (types.get(t.mug_id, ""), t.position_m[0], t.position_m[1])
            for t in counter.cell.world.mug_truths().values()
            if not t.held
        }
    return {}


def cross_check(world: RecordedWorld, truth: Mapping[str, tuple[str, float, float]]) -> str:
    """How far the cell built from the header's scene was from what the recording saw: for each mug the
    recording has standing (counter or tray), the nearest cell mug of its type."""
    if not truth:
        return "no simulated world to compare"
    worst = 0.0
    missing = []
    for m in world.mugs:
        if m.where == "gripper":
            continue
        near = [math.hypot(x - m.x_m, y - m.y_m) for t, x, y in truth.values() if t == m.type]
        if not near:
            missing.append(m.mug_id)
            continue
        worst = max(worst, min(near))
    line = f"the header's world was within {worst * 1000:.1f} mm of what the recording saw"
    if missing:
        line += f"; it has no mug of the type of {' '.join(missing)}"
    return line


@dataclass(frozen=True, slots=True)
class Resimulated:
    """What a replay's stand-in did, for its report: its world, how it was built, and from when (seconds
    from the job's start) the job went on in it, set to ``seen`` (None: every input came from the
    recording)."""

    world: str  # kinematic or mujoco
    from_header: bool  # built from the header's scene (only a cross-check), else from the recording
    from_s: float | None = None
    seen: RecordedWorld | None = None
    check: str | None = None  # the header-built cell against what the recording saw, at ``from_s``

    def to_json(self) -> dict[str, object] | None:
        if self.from_s is None or self.seen is None:
            return None
        return {
            "world": self.world,
            "from_s": round(self.from_s, 6),
            "model_based": True,
            "seen": self.seen.to_json(),
            "header_check": self.check,
        }

    def lines(self) -> list[str]:
        built = "from the header's scene (a cross-check)" if self.from_header else "from the recording"
        if self.from_s is None or self.seen is None:
            return [
                f"not re-simulated: every input came from the recording (stand-in: {self.world} cell, built "
                f"{built})"
            ]
        out = [
            f"re-simulated from {self.from_s:.3f} s in the {self.world} stand-in, set to what the recording "
            f"saw then: {self.seen.describe()}; what follows is model-based (the {self.world} cell's "
            "devices and world, not the recorded inputs)"
        ]
        if self.check is not None:
            out.append(f"cross-check: {self.check}")
        return out


class Resimulation:
    """The stand-in cell of one replay, set to what the recording saw.

    A cell built from the header's scene (a simulated recording) is only cross-checked against what the
    recording saw; any other (a robot's recording, a job that continued an earlier tray) is first set to
    the counter as the camera first saw it when the job starts. At the first divergence or injected fault
    the cell is set to the world the recording saw at that instant (``world_at``), and the job goes on in
    it: from there, the replay is model-based."""

    def __init__(self, session: RecordedSession, backend: Backend, *, world: str, from_header: bool) -> None:
        self._session = session
        self._backend = backend
        self._arm = ArmModel.load()
        self._catalogue = session.config.mug_catalogue()
        self.result = Resimulated(world, from_header)

    def job_started(self) -> None:
        """The replay's job started: a cell not built from the header gets the recording's first look."""
        if self.result.from_header:
            return
        first = first_look_s(self._session)
        seen = world_at(self._session, first if first is not None else 0.0, arm=self._arm)
        restage(self._backend, seen, self._catalogue)

    def take_over(self, t_s: float) -> None:
        """The replay diverged (or a fault fired) at ``t_s``: set the cell to what the recording saw then."""
        if self.result.from_s is not None:
            return
        seen = world_at(self._session, t_s, arm=self._arm)
        check = cross_check(seen, cell_truth(self._backend)) if self.result.from_header else None
        restage(self._backend, seen, self._catalogue)
        self.result = replace(self.result, from_s=t_s, seen=seen, check=check)


def continues_earlier_job(session: RecordedSession) -> bool:
    """Whether the job went on with the scene an earlier job of its daemon left (the mugs on the tray, the
    counter it knew): it was started by a ``start`` command that named neither a dataset nor mugs."""
    from daemon.commands_handler import StartBody

    # The start that began it: logged with its reply, so after the start transition on the wall clock.
    starting = session.starting_command()
    if starting is None:
        return False
    command = starting.message
    assert isinstance(command, Command)  # (``commands()`` keeps only those)
    # The start body as the operator sent it, read as the daemon reads it (``StartBody``); one the
    # daemon refuses started nothing.
    try:
        body = convert(json.loads(command.payload or "{}"), StartBody, root="start")
    except (ValueError, Invalid):
        return False
    return body.dataset is None and body.mugs is None


def carried_over(session: RecordedSession) -> JobContext:
    """What the earlier jobs left a job that continued them, as the recording has it: the mugs on the tray
    where the header's scene says they were, the counter as the job first saw it (so that its first look
    names the mugs as it did) and the next new mug's id."""
    from daemon.job.context import JobContext
    from daemon.job.requests import PlannerRequest
    from planning.interfaces import MugPose, TraySlot
    from planning.placement.problem import TrayMug

    config = session.config
    catalogue = config.mug_catalogue()
    tray = config.cell.tray
    first = first_look_s(session)
    seen = world_at(session, first if first is not None else 0.0)
    on_tray, tray_mugs = [], []
    for m in seen.on("tray"):
        on_tray.append(TraySlot(m.mug_id, m.type, m.x_m, m.y_m))
        spec = catalogue.get(m.type)
        r_mm = ((spec.diameter_mm if spec else 0.0) + config.planner.tolerance_mm) / 2.0
        bx, by = tray.to_tray_mm(m.x_m, m.y_m)
        tray_mugs.append(TrayMug(m.mug_id, m.type, round(bx - r_mm), round(by - r_mm)))
    counter = {
        m.mug_id: MugPose(m.mug_id, m.type, m.x_m, m.y_m, m.handle_yaw_rad, m.upside_down)
        for m in seen.on("counter")
    }
    numbers = [int(m.mug_id[1:]) for m in seen.mugs if m.mug_id[:1] == "m" and m.mug_id[1:].isdigit()]
    next_id = max(numbers, default=0) + 1
    carried = header_part(session.job, HeaderJob).carried
    if not isinstance(carried, UnsetType):  # the header says what the job carried over: exactly that
        # (its entries are the job's own dataclasses as JSON: their constructors judge them, one line if not)
        try:
            on_tray = [TraySlot(**slot) for slot in carried["on_tray"]]
            tray_mugs = [TrayMug(**mug) for mug in carried["tray_mugs"]]
            counter = {m["mug_id"]: MugPose(**m) for m in carried.get("counter", ())} or counter
            next_id = int(carried["next_id"])
        except (KeyError, TypeError, ValueError) as e:
            raise ReplayError(
                f"{session.path}: the header's job.carried is not what a job carries: {e}"
            ) from e
    return JobContext(
        planner=PlannerRequest().options(config.planner),
        counter=counter,
        on_tray=on_tray,
        tray_mugs=tray_mugs,
        next_id=next_id,
    )


def first_look_s(session: RecordedSession) -> float | None:
    """When the job first looked at the counter (its first ``detections``), seconds from its start."""
    for m in session.read.messages:
        if m.log_time_ns >= session.start_ns and topic_suffix(m.topic) == "detections":
            return (m.log_time_ns - session.start_ns) / 1e9
    return None


__all__ = [
    "STAND_INS",
    "RecordedWorld",
    "Resimulated",
    "Resimulation",
    "WorldMug",
    "carried_over",
    "cell_truth",
    "continues_earlier_job",
    "cross_check",
    "first_look_s",
    "restage",
    "world_at",
]
