"""The planning scene every stage of a cycle plans in: the arm, the cell, the mug catalogue and the
planner's settings, with the geometry they share (grasp targets, the collision world, timed paths).

Like MoveIt Task Constructor's planning scene, it is read by the stages (``planning.motion.stages``) and
never changed by them; ``CyclePlanner`` builds one and composes the stages over it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from description.arm import JOINT_LIMITS
from description.cell import CellLayout
from description.thesis import MugSpec
from drivers.interfaces import FloatArray, JointTrajectory
from planning.arm.calibration import PositionCorrection
from planning.arm.grasp import side_grasp
from planning.arm.model import ArmModel, JointValues
from planning.arm.targets import GraspKind, GraspTarget, IkResult
from planning.interfaces import MotionRefused, MugPose, TraySlot
from planning.motion.cell import carry_height_m
from planning.motion.collision import (
    BASE_COLUMN,
    Box,
    CollisionWorld,
    Cylinder,
    Sweep,
    SweepKey,
    mug_obstacles,
    tray_walls,
)
from planning.motion.remembered import Lru
from planning.motion.trajectory import JointPath, plan_path

# The last stretch of every set-down and its speed (``CyclePlanner``'s ``set_down_slow_m`` and
# ``set_down_speed_m_s``): the defaults of every planner built without the daemon's ``[arm]`` settings.
SET_DOWN_SLOW_M = 0.03
SET_DOWN_SPEED_M_S = 0.01


@dataclass(frozen=True, slots=True)
class Settings:
    """How the cycle is planned (``CyclePlanner``'s keyword arguments, described there)."""

    control_rate_hz: float = 50.0
    back_off_m: tuple[float, ...] = (0.06, 0.03, 0.0)
    side_clearance_m: float = 0.004
    release_gap_m: float = 0.008
    release_openings_m: tuple[float, ...] = (0.012, 0.006)
    fine_speed_m_s: float = 0.08
    set_down_slow_m: float = SET_DOWN_SLOW_M
    set_down_speed_m_s: float = SET_DOWN_SPEED_M_S
    correction: PositionCorrection | None = None


# How many IK solutions, timed paths and gripper sweeps a scene remembers: a ds4 plan check computes about
# 5,700, 700 and 800 distinct ones, and all it remembers (with the planner's cycles) takes about 15 MB.
_IK_REMEMBERED = 8192
_PATHS_REMEMBERED = 2048
_SWEEPS_REMEMBERED = 1024
_IkKey = tuple[bytes, GraspKind, bytes]
_PathKey = tuple[bytes, tuple[int, ...], str, str, str]


class Scene:
    """The arm in its cell with the mugs it may meet, and the settings of the planner that plans in it."""

    def __init__(
        self, arm: ArmModel, cell: CellLayout, catalogue: Mapping[str, MugSpec], settings: Settings
    ) -> None:
        self.arm = arm
        self.cell = cell
        self.catalogue = dict(catalogue)
        self.settings = settings
        tallest = max(m.height_mm for m in self.catalogue.values()) / 1000.0
        # Mugs on the tray stand on its base, so the tallest obstacle is that much higher there.
        self.carry_z_m = carry_height_m(tallest + max(0.0, cell.tray.base_m))
        self.open_aperture_m = arm.gripper.aperture_m(JOINT_LIMITS["gripper"].lower_rad)
        self._forget()

    def _forget(self) -> None:
        # IK and timing are pure functions of their arguments, computed again and again by a plan check
        # (the same move tried against other obstacles, with another opening, from the same start): each
        # is remembered by its exact arguments. Only the collision checks depend on the obstacles.
        self._ik: Lru[_IkKey, IkResult] = Lru(_IK_REMEMBERED)
        self._paths: Lru[_PathKey, tuple[JointTrajectory, JointPath]] = Lru(_PATHS_REMEMBERED)
        self._sweeps: Lru[SweepKey, Sweep] = Lru(_SWEEPS_REMEMBERED)

    def __getstate__(self) -> dict[str, object]:
        """Picklable without what it remembers."""
        state = dict(self.__dict__)
        del state["_ik"], state["_paths"], state["_sweeps"]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._forget()

    def spec(self, type_name: str, what: str) -> MugSpec:
        """The catalogue's mug type ``type_name``; refused naming ``what`` has it when it is unknown."""
        try:
            return self.catalogue[type_name]
        except KeyError as e:
            raise MotionRefused(
                f"{what}: unknown mug type {type_name!r} (catalogue: {', '.join(sorted(self.catalogue))})"
            ) from e

    def path(
        self,
        waypoints: FloatArray,
        label: str,
        *,
        tool_length_m: float = 0.0,
        fine: bool = False,
        tool_speed_m_s: float | None = None,
    ) -> tuple[JointTrajectory, JointPath]:
        """The timed path through ``waypoints`` within the servo limits, at fine speed when ``fine``, the
        tool no faster than ``tool_speed_m_s`` when given (remembered by its exact arguments: the trajectory
        and path returned are shared, never changed)."""
        arr = np.ascontiguousarray(waypoints, dtype=np.float64)
        if tool_speed_m_s is None:
            tool_speed_m_s = self.settings.fine_speed_m_s if fine else math.inf
        key = (arr.tobytes(), arr.shape, label, float(tool_length_m).hex(), float(tool_speed_m_s).hex())
        return self._paths.get(
            key,
            lambda: plan_path(
                arr,
                names=self.arm.joint_names,
                max_velocity=self.arm.max_velocity,
                max_acceleration=self.arm.max_acceleration,
                rate_hz=self.settings.control_rate_hz,
                label=label,
                tool_path_length_m=tool_length_m,
                max_tool_speed_m_s=tool_speed_m_s,
            ),
        )

    def ik(self, target: GraspTarget, seed: JointValues) -> IkResult:
        """``ArmModel.ik`` of ``target`` from ``seed`` (remembered by their exact values)."""
        start = np.ascontiguousarray(seed, dtype=np.float64)
        # Bytes, not floats: -0.0 and 0.0 are equal floats but may not give the same solution.
        key = (np.array(target.position_m, dtype=np.float64).tobytes(), target.kind, start.tobytes())
        return self._ik.get(key, lambda: self.arm.ik(target, seeds=[start]))

    def grasp(self, x: float, y: float, spec: MugSpec, kind: GraspKind, z: float, what: str) -> GraspTarget:
        """The side grasp of a mug standing at (x, y), at height ``z``; refused naming ``what``."""
        try:
            return side_grasp(x, y, spec, self.arm.gripper, z_m=z, kind=kind).target
        except ValueError as e:
            raise MotionRefused(f"{what}: {e}") from e

    def clear_of(self, target: GraspTarget, back_m: float, side_m: float) -> GraspTarget:
        """Where the open gripper is clear of the mug of a grasp: ``back_m`` back along the approach and
        ``side_m`` away from the mug on the thumb's side (the thumb touches the brim at the grasp)."""
        rotation = target.rotation()
        assert rotation is not None
        approach, mug_side = rotation[:, 2], rotation[:, 1]
        shift = -back_m * approach - side_m * mug_side
        x, y, z = target.position_m
        return GraspTarget((x + float(shift[0]), y + float(shift[1]), z), target.kind)

    def world(
        self,
        counter: Sequence[MugPose],
        placed: Sequence[TraySlot],
        *,
        target: MugPose | None = None,
        target_spec: MugSpec | None = None,
        target_floor: float = 0.0,
    ) -> CollisionWorld:
        """The collision world of the base, the tray's walls, the counter's mugs, the mugs placed on the tray
        and the ``target`` mug standing on ``target_floor``."""
        cylinders: list[Cylinder] = [BASE_COLUMN]
        for m in counter:
            cylinders += mug_obstacles(
                f"mug {m.mug_id}",
                m.x_m,
                m.y_m,
                self.spec(m.type, f"mug {m.mug_id}"),
                handle_yaw_rad=m.handle_yaw_rad,
            )
        for s in placed:
            yaw = s.handle_yaw_rad if s.handle_yaw_rad is not None else (math.pi / 2 if s.rotated else 0.0)
            spec = self.spec(s.type, f"mug {s.mug_id}")
            floor = self.cell.tray.base_m
            cylinders += mug_obstacles(
                f"mug {s.mug_id}", s.x_m, s.y_m, spec, handle_yaw_rad=yaw, floor_z=floor
            )
        if target is not None and target_spec is not None:
            cylinders += mug_obstacles(
                f"mug {target.mug_id}",
                target.x_m,
                target.y_m,
                target_spec,
                handle_yaw_rad=target.handle_yaw_rad,
                floor_z=target_floor,
            )
        walls: list[Box] = tray_walls(
            self.cell.tray.region_m,
            height=self.cell.tray.wall_height_m,
            thickness=self.cell.tray.wall_thickness_m,
        )
        return CollisionWorld(self.arm, cylinders, walls, sweeps=self._sweeps)

    def checked_q(self, q: Sequence[float], name: str) -> FloatArray:
        """``q`` as joint angles of the arm; refused when it has the wrong size, is not finite or is out of
        the joint limits."""
        arr = np.asarray(q, dtype=np.float64).reshape(-1)
        if arr.shape != (self.arm.dof,):
            raise MotionRefused(f"{name}: expected {self.arm.dof} joint angles, got {arr.size}")
        if not np.all(np.isfinite(arr)):
            raise MotionRefused(f"{name}: joint angles must be finite, got {[float(v) for v in arr]}")
        violations = self.arm.limit_violations(arr, tol=1e-6)
        if violations:
            raise MotionRefused(f"{name}: {'; '.join(violations)}")
        return arr
