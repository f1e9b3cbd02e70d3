"""The kinematic cell's world: the mugs, the arm's joint angles, the gripper jaw, on the clock it is given.

A placeholder for the physics simulation: no dynamics, no collisions. A mug is taken when the gripper closes
with the mug's axis where the grasp geometry puts a held mug (within ``GRASP_CAPTURE_M``); while held it
follows the grasp frame rigidly; when the jaw opens it lands on the surface below (tray or counter), upside
down if the gripper turned it over. The forward kinematics come from the arm model of ``planning.arm``, so the
cell agrees with the motion planner about where the gripper is.

Faults for tests and replays: ``slip_next_grasp`` pushes the mug away as the jaw closes (the grasp fails),
``drop_held_mug`` lets a carried mug fall, ``move_mug`` shifts a mug on the counter. The devices' own faults
are the device simulators' (``sim.kinematic.cell``: the servo chain and the FSR Arduino behind the real
drivers, the camera behind the driver's frame checks), as in the MuJoCo cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import structlog

from drivers.interfaces import Clock, FloatArray
from planning.arm import ArmModel

log = structlog.get_logger("sim.kinematic")

# The kinematic cell's own parameters (a stand-in, not thesis figures).
OPEN_APERTURE_M = 0.12  # jaw opening when open: wider than the big mug's 91 mm brim
PAD_STIFFNESS_N_M = 2000.0  # force per metre of squeeze once both pads touch the mug
GRASP_CAPTURE_M = 0.02  # how far a mug's axis may be from where a held mug sits and still be taken
SLIP_DISTANCE_M = 0.04  # how far a slipping grasp pushes the mug away

Where = Literal["counter", "gripper", "tray"]


@dataclass(frozen=True, slots=True)
class MugGeometry:
    """Brim diameter and height of one mug type, metres."""

    diameter_m: float
    height_m: float


@dataclass(frozen=True, slots=True)
class SimMug:
    """A mug of the simulated cell: its axis on the surface it stands on (world frame, metres)."""

    mug_id: str
    type: str
    x_m: float
    y_m: float
    upside_down: bool = False
    handle_yaw_rad: float = 0.0
    where: Where = "counter"


class KinematicWorld:
    """The state of the kinematic cell; the simulated devices read and change it, moving on ``clock`` (a
    simulated clock runs them as fast as the machine allows, the wall clock in real time)."""

    def __init__(
        self,
        arm: ArmModel,
        mugs: list[SimMug],
        mug_geometry: dict[str, MugGeometry],
        *,
        tray_origin_m: tuple[float, float],
        tray_size_m: tuple[float, float],
        clock: Clock,
        q0: FloatArray | None = None,
    ) -> None:
        unknown = sorted({m.type for m in mugs} - set(mug_geometry))
        if unknown:
            raise ValueError(f"mug types {unknown} are not in the catalogue {sorted(mug_geometry)}")
        self.arm = arm
        self.mug_geometry = mug_geometry
        self.tray_origin_m = tray_origin_m
        self.tray_size_m = tray_size_m
        self.clock = clock
        self._mugs: dict[str, SimMug] = {m.mug_id: m for m in mugs}
        self._held_moved = False  # the arm moved since the held mug's pose was last worked out
        self.q: FloatArray = np.zeros(arm.dof) if q0 is None else np.asarray(q0, dtype=np.float64).copy()
        self.aperture_m = OPEN_APERTURE_M
        self.held: str | None = None
        self._held_local: FloatArray = np.zeros(3)
        self._held_up_local: FloatArray = np.array([0.0, 0.0, 1.0])
        self._slip_next = False

    @property
    def mugs(self) -> dict[str, SimMug]:
        """Every mug by id, where it is now (a carried one where the gripper has taken it)."""
        if self._held_moved:
            self._held_moved = False
            self._place_held()
        return self._mugs

    @mugs.setter
    def mugs(self, mugs: dict[str, SimMug]) -> None:
        self._mugs = mugs
        self._held_moved = False

    def set_mugs(self, mugs: list[SimMug]) -> None:
        """Put a new set of mugs on the counter (a new job in simulation); the gripper is empty after it."""
        self.mugs = {m.mug_id: m for m in mugs}
        self.held = None

    def restage(
        self,
        mugs: list[SimMug],
        *,
        q: FloatArray | tuple[float, ...] | None = None,
        held: SimMug | None = None,
        force_n: float = 0.0,
    ) -> None:
        """Set the world to a state seen elsewhere (a recording's, for a re-simulation): ``mugs`` standing
        where they are (counter or tray), the arm at ``q`` (None: where it is) and ``held`` in the gripper,
        its axis where a held mug's is at that pose, squeezed with ``force_n`` (at least what a grasp
        holds with). The devices' faults are left as they are."""
        unknown = sorted({m.type for m in [*mugs, *([held] if held else [])]} - set(self.mug_geometry))
        if unknown:
            raise ValueError(f"mug types {unknown} are not in the catalogue {sorted(self.mug_geometry)}")
        if q is not None:
            self.q = np.asarray(q, dtype=np.float64).copy()
        self.mugs = {m.mug_id: replace(m, where="tray" if m.where == "tray" else "counter") for m in mugs}
        self.held = None
        self._slip_next = False
        if held is None:
            return
        p, r = self.grasp_pose()
        geo = self.mug_geometry[held.type]
        axis = p + r[:, 1] * (geo.diameter_m / 2 - self.arm.gripper.thumb_width_m)
        self.mugs[held.mug_id] = replace(held, x_m=float(axis[0]), y_m=float(axis[1]), where="counter")
        self._take(held.mug_id)
        squeeze = max(force_n, 0.0) / PAD_STIFFNESS_N_M
        self.aperture_m = geo.diameter_m - max(squeeze, 1e-3)
        log.info("sim_world_restaged", mugs=len(mugs), held=held.mug_id)

    # --- faults ---------------------------------------------------------------------------------------

    def slip_next_grasp(self) -> None:
        self._slip_next = True

    def drop_held_mug(self) -> str | None:
        """Let the carried mug fall where it is; returns its id (None when nothing was held)."""
        mug_id = self.held
        if mug_id is not None:
            self._land(mug_id)
            log.info("sim_mug_dropped", mug_id=mug_id)
        return mug_id

    def move_mug(self, mug_id: str, dx_m: float, dy_m: float) -> None:
        """Shift a mug standing on the counter (someone moved it); ValueError for one that is not there."""
        mug = self.mugs.get(mug_id)
        if mug is None or mug.where != "counter":
            raise ValueError(f"mug {mug_id} is not on the counter")
        self.mugs[mug_id] = replace(mug, x_m=mug.x_m + dx_m, y_m=mug.y_m + dy_m)
        log.info("sim_mug_moved", mug_id=mug_id, dx_m=dx_m, dy_m=dy_m)

    # --- arm --------------------------------------------------------------------------------------------

    def grasp_pose(self) -> tuple[FloatArray, FloatArray]:
        return self.arm.fk(self.q)

    def set_q(self, q: FloatArray) -> None:
        """Move the arm to ``q``; a carried mug goes with it (worked out when someone looks at the mugs:
        the arm moves many times between looks)."""
        self.q = np.asarray(q, dtype=np.float64).copy()
        if self.held is not None:
            self._held_moved = True

    def _place_held(self) -> None:
        """Put the carried mug where the gripper holds it at the arm's pose."""
        if self.held is None:
            return
        p, r = self.grasp_pose()
        base = p + r @ self._held_local
        up = r @ self._held_up_local
        mug = self._mugs[self.held]
        self._mugs[self.held] = replace(
            mug, x_m=float(base[0]), y_m=float(base[1]), upside_down=bool(up[2] < 0)
        )

    # --- gripper ---------------------------------------------------------------------------------------

    def pad_force_n(self) -> float:
        if self.held is None:
            return 0.0
        squeeze = self.mug_geometry[self._mugs[self.held].type].diameter_m - self.aperture_m
        return max(0.0, PAD_STIFFNESS_N_M * squeeze)

    def contact_aperture_m(self) -> float | None:
        """The aperture at which the closing jaw meets a mug, or None when no mug is between the pads."""
        mug_id = self.held or self._mug_between_pads()
        if mug_id is None:
            return None
        if self._slip_next and self.held is None:
            self._slip_next = False
            self._push_away(mug_id)
            return None
        self._take(mug_id)
        return self.mug_geometry[self.mugs[mug_id].type].diameter_m

    def release(self) -> None:
        if self.held is not None:
            self._land(self.held)

    def _mug_between_pads(self) -> str | None:
        p, r = self.grasp_pose()
        best: tuple[float, str] | None = None
        for mug in self.mugs.values():
            if mug.where != "counter":
                continue
            geo = self.mug_geometry[mug.type]
            expected = p + r[:, 1] * (geo.diameter_m / 2 - self.arm.gripper.thumb_width_m)
            d = math.hypot(expected[0] - mug.x_m, expected[1] - mug.y_m)
            if d <= GRASP_CAPTURE_M and 0.0 < p[2] < geo.height_m and (best is None or d < best[0]):
                best = (d, mug.mug_id)
        return best[1] if best else None

    def _take(self, mug_id: str) -> None:
        if self.held == mug_id:
            return
        p, r = self.grasp_pose()
        mug = self.mugs[mug_id]
        base = np.array([mug.x_m, mug.y_m, 0.0])
        self._held_local = r.T @ (base - p)
        up = np.array([0.0, 0.0, -1.0 if mug.upside_down else 1.0])
        self._held_up_local = r.T @ up
        self.held = mug_id
        self.mugs[mug_id] = replace(mug, where="gripper")

    def _push_away(self, mug_id: str) -> None:
        p, _ = self.grasp_pose()
        mug = self.mugs[mug_id]
        away = np.array([mug.x_m - p[0], mug.y_m - p[1]])
        norm = float(np.linalg.norm(away)) or 1.0
        x, y = mug.x_m + SLIP_DISTANCE_M * away[0] / norm, mug.y_m + SLIP_DISTANCE_M * away[1] / norm
        self.mugs[mug_id] = replace(mug, x_m=float(x), y_m=float(y))
        log.info("sim_grasp_slipped", mug_id=mug_id)

    def _land(self, mug_id: str) -> None:
        mug = self.mugs[mug_id]
        ox, oy = self.tray_origin_m
        sx, sy = self.tray_size_m
        on_tray = ox <= mug.x_m <= ox + sx and oy <= mug.y_m <= oy + sy
        self.mugs[mug_id] = replace(mug, where="tray" if on_tray else "counter")
        self.held = None

    def scene(self) -> dict[str, object]:
        """The world as JSON: the mugs' true poses, the tray and the arm (for the recording's header)."""
        return {
            "world": "kinematic",
            "tray": {"origin_m": list(self.tray_origin_m), "size_m": list(self.tray_size_m)},
            "arm_q": [round(float(v), 6) for v in self.q],
            "mugs": [
                {
                    "id": m.mug_id,
                    "type": m.type,
                    "x_m": round(float(m.x_m), 5),
                    "y_m": round(float(m.y_m), 5),
                    "upside_down": bool(m.upside_down),  # the world may hold a numpy bool
                    "where": m.where,
                }
                for m in self.mugs.values()
            ],
        }
