"""The arm as Pinocchio sees it: forward kinematics of the grasp point, and damped-least-squares inverse
kinematics with joint limits and several seeds.

Only the five arm joints are planned; the gripper joint is locked open in the kinematic model (the gripper
is driven on its own by ``drivers.interfaces.GripperDriver``). For the thesis arm the solver starts from a
closed-form guess (turn towards the target, solve the shoulder-elbow triangle, set the wrist pitch and
roll) and lets Pinocchio remove what the small offsets of Table 3.1 leave; any other URDF falls back to a
fixed fan of seeds. An ``ArmModel`` owns one Pinocchio ``Data`` and is not thread-safe: use ``copy()``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import structlog

from description import thesis
from description.arm import BUNDLED_URDF, GRASP_FRAME, GripperGeometry
from description.servos import SERVO_MODELS, ServoModel
from drivers.interfaces import FloatArray
from planning.arm.errors import ArmModelError, InvalidTarget
from planning.arm.targets import GraspKind, GraspTarget, IkResult

log = structlog.get_logger(__name__)

THESIS_ARM_JOINTS = tuple(j for j, _ in thesis.JOINT_SERVOS[:5])

# Joint angles as callers hold them: a list, a tuple or a float array, in ``ArmModel.joint_names`` order.
JointValues = Sequence[float] | FloatArray

# Weight of one radian of orientation error against one metre of position error in the solver.
_ROTATION_WEIGHT_M = 0.1
_POSITION_TOL_M = 1e-3
_ROTATION_TOL_RAD = 2e-3
_CONVERGED_M = 1e-5  # 10 µm: a hundred times inside the 1 mm target, well below servo resolution
_STALL_ITERS = 8
_POSITION_PITCHES_DEG = (0, -15, -30, -45, -60, -75, -90, 15, 30, 45, 60, 75, 90)


def _lapack_solve1() -> Callable[..., object] | None:
    """numpy's private LAPACK gufunc behind ``np.linalg.solve`` for one right-hand side, or None where this
    numpy has no such thing (it is not public API: a numpy that moves it must not break the planner)."""
    try:
        from numpy.linalg import _umath_linalg
    except ImportError:
        return None
    solve1 = getattr(_umath_linalg, "solve1", None)
    return solve1 if callable(solve1) else None


_SOLVE1 = _lapack_solve1()


def _solve_linear(a: FloatArray, b: FloatArray) -> FloatArray:
    """``np.linalg.solve(a, b)`` for a square ``a`` that is never singular (damped: positive definite), by
    the LAPACK routine it calls, without its checks (a fifth of the time of a whole IK iteration); by
    ``np.linalg.solve`` itself where numpy does not offer that routine."""
    if _SOLVE1 is None:
        return np.asarray(np.linalg.solve(a, b), dtype=np.float64)
    return np.asarray(_SOLVE1(a, b, signature="dd->d"), dtype=np.float64)


# ``ndarray.max`` without its Python wrapper (numpy's ``_methods._amax``): the same reduction, asked twice
# per IK iteration, where the wrapper cost as much as the reduction.
_largest = np.maximum.reduce


def _norm(v: FloatArray) -> float:
    """``np.linalg.norm`` of a vector, as it works it out (the square root of v . v), without its wrapper."""
    return math.sqrt(float(v.dot(v)))


@functools.lru_cache(maxsize=8)
def _damping_matrix(damping: float, n_rows: int) -> FloatArray:
    """``damping**2`` times the identity, made once per damping and size (read-only, as it is shared)."""
    damped = (damping * damping) * np.eye(n_rows)
    damped.flags.writeable = False
    return damped


@dataclass(frozen=True, slots=True)
class _Seed:
    """A starting pose for the solver; closed-form seeds carry a label naming their branch."""

    q: FloatArray
    label: str = ""
    exact: bool = False  # a closed-form solution (the shoulder-elbow triangle closes)


def _wrap_into(angle: float, lower: float, upper: float) -> float:
    """``angle`` shifted by whole turns into [lower, upper] when possible, else to the nearest turn of it."""
    wrapped = math.remainder(angle, 2 * math.pi)
    for candidate in (wrapped, wrapped + 2 * math.pi, wrapped - 2 * math.pi):
        if lower <= candidate <= upper:
            return candidate
    return wrapped


@dataclass(frozen=True, slots=True)
class _Chain:
    """A serial chain of joints rotating about x, y or z, as numpy arrays: per joint its placement in its
    parent (rotation, translation) and its axis (0, 1, 2); the tool frame's placement in the last joint."""

    joints: tuple[tuple[FloatArray, FloatArray, int], ...]
    tool: tuple[FloatArray, FloatArray]


_AXES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


def _serial_chain(model: pin.Model, tool_id: int) -> _Chain | None:
    """The model as a ``_Chain``, or None when it is not one (a prismatic or unaligned joint, a branch)."""
    joints = []
    for i in range(1, model.njoints):
        axis = _AXES.get(model.joints[i].shortname())
        if axis is None or model.parents[i] != i - 1:
            return None
        placement = model.jointPlacements[i]
        joints.append((placement.rotation.copy(), placement.translation.copy(), axis))
    frame = model.frames[tool_id]
    if frame.parentJoint != model.njoints - 1:
        return None
    return _Chain(tuple(joints), (frame.placement.rotation.copy(), frame.placement.translation.copy()))


def _axis_rotations(axis: int, angles: FloatArray) -> FloatArray:
    """Rotations (N, 3, 3) by ``angles`` about the x, y or z axis (0, 1, 2)."""
    c, s = np.cos(angles), np.sin(angles)
    out = np.zeros((len(angles), 3, 3))
    a, b = (axis + 1) % 3, (axis + 2) % 3
    out[:, axis, axis] = 1.0
    out[:, a, a] = c
    out[:, b, b] = c
    out[:, b, a] = s
    out[:, a, b] = -s
    return out


@dataclass(frozen=True, slots=True)
class _PlanarArm:
    """The thesis arm's shoulder-elbow-wrist triangle, measured at q = 0, for closed-form seeds."""

    shoulder_z_m: float
    upper_m: float
    fore_m: float
    tool_m: float  # wrist-lift axis to grasp point, along the approach


class ArmModel:
    """Kinematics and dynamics of the arm's five joints, from a URDF."""

    def __init__(
        self,
        model: pin.Model,
        *,
        source: Path,
        servo_models: tuple[ServoModel, ...],
        tool_frame: str,
        gripper: GripperGeometry,
    ) -> None:
        self.model = model
        self.data = model.createData()
        self.source = source
        self.servo_models = servo_models
        self.gripper = gripper
        self.tool_frame = tool_frame
        self.joint_names: tuple[str, ...] = tuple(model.names[1:])
        self.lower = np.asarray(model.lowerPositionLimit, dtype=np.float64).copy()
        self.upper = np.asarray(model.upperPositionLimit, dtype=np.float64).copy()
        self.max_velocity = np.array([s.max_speed_rad_s for s in servo_models])
        self.max_acceleration = np.array([s.max_accel_rad_s2 for s in servo_models])
        self._tool_id = model.getFrameId(tool_frame)
        self._chain = _serial_chain(model, self._tool_id)
        self._limits = ([float(v) for v in self.lower], [float(v) for v in self.upper])
        self._planar = self._measure_planar() if self.joint_names == THESIS_ARM_JOINTS else None

    @classmethod
    def load(
        cls,
        urdf_path: Path | None = None,
        *,
        servos: Mapping[str, str] | None = None,
        tool_frame: str = GRASP_FRAME,
        locked_joints: Sequence[str] = ("gripper",),
        gripper: GripperGeometry | None = None,
    ) -> ArmModel:
        """Build the model from a URDF (None: the bundled thesis arm). ``servos`` maps each joint to a servo
        type of ``SERVO_MODELS`` (default: the thesis's assignment); ``locked_joints`` are held at 0."""
        path = urdf_path or BUNDLED_URDF
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise ArmModelError(f"cannot read the arm URDF {path}: {e.strerror}") from e
        try:
            full = pin.buildModelFromXML(text)
        except (RuntimeError, ValueError) as e:
            raise ArmModelError(f"{path} is not a usable URDF: {e}") from e
        if not full.existFrame(tool_frame):
            raise ArmModelError(f"{path} has no frame {tool_frame!r} to use as the grasp point")
        lock_ids = []
        for name in locked_joints:
            if not full.existJointName(name):
                raise ArmModelError(f"{path} has no joint {name!r} to lock (locked_joints)")
            lock_ids.append(full.getJointId(name))
        model = pin.buildReducedModel(full, lock_ids, pin.neutral(full)) if lock_ids else full
        if model.nq != model.nv or any(model.joints[i].nq != 1 for i in range(1, model.njoints)):
            raise ArmModelError(f"{path}: only revolute or prismatic joints are supported")
        assignment = dict(servos) if servos is not None else dict(thesis.JOINT_SERVOS)
        models = []
        for name in model.names[1:]:
            servo = assignment.get(name)
            if servo not in SERVO_MODELS:
                raise ArmModelError(
                    f"joint {name!r} of {path} has servo {servo!r}; map it to one of {sorted(SERVO_MODELS)}"
                )
            models.append(SERVO_MODELS[servo])
        arm = cls(
            model,
            source=path,
            servo_models=tuple(models),
            tool_frame=tool_frame,
            gripper=gripper or GripperGeometry(),
        )
        log.debug("arm_model_loaded", urdf=str(path), joints=arm.joint_names)
        return arm

    def copy(self) -> ArmModel:
        """An independent model (own Pinocchio data) for use on another thread."""
        return ArmModel(
            self.model,
            source=self.source,
            servo_models=self.servo_models,
            tool_frame=self.tool_frame,
            gripper=self.gripper,
        )

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def joint_vector(self, q: JointValues) -> FloatArray:
        """``q`` as a float array, checked for length and finiteness (raises ``InvalidTarget``)."""
        arr = np.array(q, dtype=np.float64).reshape(-1)
        if arr.shape != (self.dof,):
            raise InvalidTarget(
                f"expected {self.dof} joint angles ({', '.join(self.joint_names)}), got {arr.size}"
            )
        if not np.isfinite(arr).all():
            raise InvalidTarget(f"joint angles must be finite, got {[float(v) for v in arr]}")
        return arr

    def limit_violations(self, q: JointValues, *, tol: float = 1e-9) -> list[str]:
        """One line per joint outside its limits (empty when ``q`` is inside)."""
        out = []
        for name, v, lo, hi in zip(self.joint_names, q, self.lower, self.upper, strict=True):
            if not lo - tol <= v <= hi + tol:
                out.append(f"{name}={v:.4f} rad is outside [{lo:.4f}, {hi:.4f}]")
        return out

    def _inside(self, q: FloatArray, tol: float = 1e-3) -> bool:
        return bool(np.all(q >= self.lower - tol) and np.all(q <= self.upper + tol))

    def fk(self, q: JointValues) -> tuple[FloatArray, FloatArray]:
        """World position (3,) and rotation (3, 3) of the grasp point at joint angles ``q``."""
        qv = self.joint_vector(q)
        pin.framesForwardKinematics(self.model, self.data, qv)
        placement = self.data.oMf[self._tool_id]
        return placement.translation.copy(), placement.rotation.copy()

    def fk_many(self, qs: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Forward kinematics of many poses ``qs`` (N, dof) at once: grasp-point positions (N, 3), rotations
        (N, 3, 3) and every joint's origin (N, dof, 3), base first; what ``fk`` and ``joint_positions`` give
        one pose at a time, to rounding (numpy over all poses instead of one Pinocchio call per pose: the
        collision checks look at thousands of poses per cycle)."""
        qs = np.asarray(qs, dtype=np.float64).reshape(-1, self.dof)
        if self._chain is None:
            return self._fk_each(qs)
        n = len(qs)
        rotation = np.broadcast_to(np.eye(3), (n, 3, 3))
        position = np.zeros((n, 3))
        origins = np.empty((n, self.dof, 3))
        for j, (placement_r, placement_p, axis) in enumerate(self._chain.joints):
            position = position + rotation @ placement_p
            rotation = rotation @ (placement_r @ _axis_rotations(axis, qs[:, j]))
            origins[:, j] = position
        tool_r, tool_p = self._chain.tool
        return position + rotation @ tool_p, rotation @ tool_r, origins

    def _fk_each(self, qs: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``fk_many`` one Pinocchio call per pose, for a chain ``fk_many`` cannot do in numpy."""
        positions, rotations, origins = [], [], []
        for q in qs:
            p, r = self.fk(q)
            positions.append(p)
            rotations.append(r)
            origins.append([self.data.oMi[i].translation.copy() for i in range(1, self.model.njoints)])
        shape = (len(qs), self.dof, 3)
        return (
            np.array(positions).reshape(-1, 3),
            np.array(rotations).reshape(-1, 3, 3),
            np.array(origins).reshape(shape),
        )

    def joint_positions(self, q: JointValues) -> FloatArray:
        """World positions (n, 3) of every joint axis origin, base first, at ``q``."""
        qv = self.joint_vector(q)
        pin.forwardKinematics(self.model, self.data, qv)
        return np.array([self.data.oMi[i].translation for i in range(1, self.model.njoints)])

    def ik(
        self,
        target: GraspTarget,
        *,
        seeds: Sequence[JointValues] = (),
        max_iters: int = 60,
        damping: float = 1e-3,
    ) -> IkResult:
        """Joint angles that put the grasp point on ``target``, inside the joint limits.

        Seeds are tried in order (the caller's first, then closed-form guesses, then a fixed fan); the first
        solution within 1 mm and 2 mrad wins, so a seed near the current pose gives a nearby solution."""
        if not target.is_finite:
            return IkResult(
                False, None, math.inf, f"target position is not finite: {list(target.position_m)}"
            )
        goal_p = np.asarray(target.position_m, dtype=np.float64)
        goal_r = target.rotation()
        unreachable = self._out_of_reach(goal_p, target)
        if unreachable:
            return IkResult(False, None, math.inf, unreachable)
        best: IkResult | None = None
        total_iters = 0
        closed_form = self._planar is not None and goal_r is not None
        seeds_tried = 0
        limit_reasons: list[str] = []
        for seed in self._seeds(goal_p, goal_r, seeds):
            if closed_form and seed.label:
                # A fully specified grasp has only the closed-form solutions; one outside the limits cannot
                # be pulled inside by the solver, so say which joint is in the way instead of iterating.
                outside = self.limit_violations(seed.q, tol=1e-3)
                if outside:
                    limit_reasons.append(f"{seed.label}: {outside[0]}")
                    continue
            seeds_tried += 1
            q, pos_err, rot_err, iters = self._solve(
                seed.q, goal_p, goal_r, max_iters=max_iters, damping=damping
            )
            total_iters += iters
            ok = pos_err <= _POSITION_TOL_M and rot_err <= _ROTATION_TOL_RAD
            result = IkResult(ok, tuple(q.tolist()), pos_err, "", rot_err, total_iters)
            if ok:
                return result
            if best is None or pos_err + rot_err * _ROTATION_WEIGHT_M < best.residual_m + (
                best.orientation_error_rad * _ROTATION_WEIGHT_M
            ):
                best = result
        if best is None:
            # The two reaching-forward branches say enough; the over-the-shoulder ones rarely matter.
            reason = "no solution within the joint limits (" + "; ".join(limit_reasons[:2]) + ")"
            return IkResult(False, None, math.inf, reason, math.inf, total_iters)
        assert best.q is not None
        at_limit = [
            f"{name} at {'lower' if abs(v - lo) < 1e-6 else 'upper'} limit"
            for name, v, lo, hi in zip(self.joint_names, best.q, self.lower, self.upper, strict=True)
            if abs(v - lo) < 1e-6 or abs(v - hi) < 1e-6
        ]
        reason = (
            f"no solution within the joint limits: best residual {best.residual_m * 1000:.1f} mm, "
            f"{math.degrees(best.orientation_error_rad):.1f} deg"
            + (f" ({', '.join(at_limit)})" if at_limit else "")
        )
        return IkResult(False, None, best.residual_m, reason, best.orientation_error_rad, total_iters)

    def _solve(
        self,
        seed: FloatArray,
        goal_p: FloatArray,
        goal_r: FloatArray | None,
        *,
        max_iters: int,
        damping: float,
    ) -> tuple[FloatArray, float, float, int]:
        # Damped least squares. The arithmetic is that of ``np.clip``, ``np.linalg.norm`` and
        # ``np.linalg.solve`` (the same LAPACK solve), called without their Python wrappers: an iteration
        # costs a few microseconds of numerical work and the wrappers cost more than that. Only the tool
        # frame's placement is brought up to date (``placement`` is a live view of it in ``data``), and the
        # position-only error has no rotation rows to fill.
        lower, upper = self.lower, self.upper
        q = np.clip(seed, lower, upper)
        n_rows = 3 if goal_r is None else 6
        damped = _damping_matrix(damping, n_rows)
        model, data, tool_id = self.model, self.data, self._tool_id
        placement = data.oMf[tool_id]
        pos_err = rot_err = math.inf
        best_total, best_it = math.inf, 0
        for it in range(1, max_iters + 1):
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacement(model, data, tool_id)
            e_p = goal_p - placement.translation
            pos_err = _norm(e_p)
            if goal_r is None:
                e = e_p
                rot_err = 0.0
            else:
                e_r = pin.log3(goal_r @ placement.rotation.T) * _ROTATION_WEIGHT_M
                rot_err = _norm(e_r) / _ROTATION_WEIGHT_M
                e = np.concatenate((e_p, e_r))
            if pos_err < _CONVERGED_M and rot_err < _CONVERGED_M / _ROTATION_WEIGHT_M:
                return q, pos_err, rot_err, it
            # A new C-ordered array each time: its rows can be weighted in place (the three of a position
            # target are a view of its first rows, laid out as a copy of them would be).
            J = pin.getFrameJacobian(model, data, tool_id, pin.LOCAL_WORLD_ALIGNED)[:n_rows]
            J[3:] *= _ROTATION_WEIGHT_M
            dq = J.T @ _solve_linear(J @ J.T + damped, e)
            step = float(_largest(abs(dq)))
            if step > 0.5:
                dq *= 0.5 / step
            q_next = np.minimum(np.maximum(q + dq, lower), upper)
            if float(_largest(abs(q_next - q))) < 1e-10:
                return q, pos_err, rot_err, it
            q = q_next
            total = pos_err + rot_err * _ROTATION_WEIGHT_M
            if total < best_total * 0.99:
                best_total, best_it = total, it
            elif it - best_it >= _STALL_ITERS:
                return q, pos_err, rot_err, it
        return q, pos_err, rot_err, max_iters

    def _seeds(
        self, goal_p: FloatArray, goal_r: FloatArray | None, user: Sequence[JointValues]
    ) -> Iterable[_Seed]:
        for s in user:
            yield _Seed(self.joint_vector(s))
        if self._planar is not None:
            if goal_r is not None:
                for flipped in (False, True):
                    for elbow_up in (True, False):
                        yield self._closed_form_seed(
                            goal_p, goal_r, goal_r[:, 2], elbow_up=elbow_up, flipped=flipped
                        )
                return
            yield from self._position_fan(goal_p)
        yield _Seed((self.lower + self.upper) / 2)
        yield _Seed(np.clip(np.zeros(self.dof), self.lower, self.upper))
        rng = np.random.default_rng(0)
        for _ in range(4):
            yield _Seed(rng.uniform(self.lower, self.upper))

    def _position_fan(self, goal_p: FloatArray) -> list[_Seed]:
        """Position only: the closed form for a fan of approach pitches (level first, then down, then up),
        both elbows, reaching forward and over the shoulder, computed at once; only exact solutions inside
        the limits are worth a try."""
        g = self._planar
        assert g is not None
        pitch = np.radians(np.repeat(_POSITION_PITCHES_DEG, 4))
        flipped = np.tile([0.0, 0.0, 1.0, 1.0], len(_POSITION_PITCHES_DEG))
        up = np.tile([-1.0, 1.0, -1.0, 1.0], len(_POSITION_PITCHES_DEG))  # -1: elbow up
        psi = math.atan2(goal_p[1], goal_p[0]) + np.pi * flipped
        # In the arm's plane the target is at +r (reaching forward) or -r (over the shoulder).
        r = math.hypot(goal_p[0], goal_p[1]) * (1.0 - 2.0 * flipped)
        r_w = r - g.tool_m * np.cos(pitch)  # the approach heads along the plane either way
        z_w = goal_p[2] - g.tool_m * np.sin(pitch) - g.shoulder_z_m
        cos_delta = (r_w**2 + z_w**2 - g.upper_m**2 - g.fore_m**2) / (2 * g.upper_m * g.fore_m)
        exact = np.abs(cos_delta) <= 1.0
        delta = up * np.arccos(np.clip(cos_delta, -1.0, 1.0))
        e1 = np.arctan2(z_w, r_w) - np.arctan2(g.fore_m * np.sin(delta), g.upper_m + g.fore_m * np.cos(delta))
        sl, el = -e1, -delta
        wl = -np.pi / 2 - pitch - sl - el
        q = np.column_stack(
            [
                np.remainder(psi + np.pi, 2 * np.pi) - np.pi,
                sl,
                el,
                np.remainder(wl + np.pi, 2 * np.pi) - np.pi,
                np.full_like(sl, -np.pi / 2),
            ]
        )
        inside = np.all((q >= self.lower - 1e-3) & (q <= self.upper + 1e-3), axis=1)
        return [_Seed(q[i], "position fan", True) for i in np.flatnonzero(exact & inside)]

    def _closed_form_seed(
        self,
        goal_p: FloatArray,
        goal_r: FloatArray | None,
        approach: FloatArray,
        *,
        elbow_up: bool,
        flipped: bool,
    ) -> _Seed:
        """Shoulder turn towards the target (or away from it, reaching back over the shoulder), the
        shoulder-elbow triangle for the wrist centre, the wrist pitch for the approach, and the wrist roll
        that matches the target's x axis."""
        g = self._planar
        assert g is not None
        psi = math.atan2(goal_p[1], goal_p[0]) + (math.pi if flipped else 0.0)
        cos_psi, sin_psi = math.cos(psi), math.sin(psi)
        ax, ay, az = float(approach[0]), float(approach[1]), float(approach[2])
        pitch = math.atan2(az, ax * cos_psi + ay * sin_psi)
        wx, wy = float(goal_p[0]) - g.tool_m * ax, float(goal_p[1]) - g.tool_m * ay
        r_w = wx * cos_psi + wy * sin_psi
        z_w = float(goal_p[2]) - g.tool_m * az - g.shoulder_z_m
        cos_delta = (r_w * r_w + z_w * z_w - g.upper_m**2 - g.fore_m**2) / (2 * g.upper_m * g.fore_m)
        exact = abs(cos_delta) <= 1.0
        delta = math.acos(max(-1.0, min(1.0, cos_delta)))
        if elbow_up:
            delta = -delta
        e1 = math.atan2(z_w, r_w) - math.atan2(
            g.fore_m * math.sin(delta), g.upper_m + g.fore_m * math.cos(delta)
        )
        sl, el = -e1, -delta
        wl = -math.pi / 2 - pitch - sl - el
        wt = -math.pi / 2
        if goal_r is not None:
            _, rot = self.fk(np.array([psi, sl, el, wl, 0.0]))
            x0, z0 = rot[:, 0], rot[:, 2]
            x_goal = goal_r[:, 0]
            wt = math.atan2(float(np.cross(x0, x_goal) @ z0), float(x0 @ x_goal))
        lower, upper = self._limits
        q = np.array(
            [_wrap_into(v, lo, hi) for v, lo, hi in zip((psi, sl, el, wl, wt), lower, upper, strict=True)]
        )
        label = f"{'elbow up' if elbow_up else 'elbow down'}{', over the shoulder' if flipped else ''}"
        return _Seed(q, label, exact)

    def _out_of_reach(self, goal_p: FloatArray, target: GraspTarget) -> str:
        """Why a target is plainly beyond the thesis arm's reach, or '' (other URDFs: always '')."""
        g = self._planar
        if g is None:
            return ""
        reach = g.upper_m + g.fore_m
        shoulder = np.array([0.0, 0.0, g.shoulder_z_m])
        if target.kind is GraspKind.POSITION:
            dist = _norm(goal_p - shoulder)
            if dist > reach + g.tool_m + 1e-3:
                return (
                    f"out of reach: {dist:.3f} m from the shoulder, the arm reaches {reach + g.tool_m:.3f} m"
                )
            return ""
        approach = target.approach()
        assert approach is not None
        wrist = goal_p - g.tool_m * approach
        dist = _norm(wrist - shoulder)
        if dist > reach + 1e-3:
            return (
                f"out of reach for a {target.kind} grasp: the wrist would be {dist:.3f} m from the shoulder, "
                f"the arm reaches {reach:.3f} m"
            )
        return ""

    def _measure_planar(self) -> _PlanarArm:
        zero = np.zeros(self.dof)
        joints = self.joint_positions(zero)
        tool, _ = self.fk(zero)
        return _PlanarArm(
            shoulder_z_m=float(joints[1][2]),
            upper_m=float(np.linalg.norm(joints[2] - joints[1])),
            fore_m=float(np.linalg.norm(joints[3] - joints[2])),
            tool_m=float(np.linalg.norm(tool - joints[3])),
        )
