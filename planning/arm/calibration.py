"""Position calibration: a smooth correction fitted from (commanded, reached) grasp-point pairs.

Appendix A of the thesis fitted quadratic error functions in (x, |y|) per height to patch its 6-DOF solver;
here the same idea is a general tool. Measure where the gripper really goes for a set of commanded targets,
fit the reached-minus-commanded error per axis as a quadratic polynomial in (x, y) plus a linear term in z,
and command ``correct(target)``: the point whose predicted reached position is the target (solved by a few
fixed-point steps, since the error is small and smooth). The fit is stored as plain numbers (``to_mapping``)
in a JSON file the config names, and read back with ``from_mapping``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.interfaces import FloatArray
from planning.arm.errors import CalibrationError

FEATURES = ("1", "x", "y", "z", "x^2", "xy", "y^2")
_MIN_PAIRS = 2 * len(FEATURES)


def _features(points: FloatArray) -> FloatArray:
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return np.column_stack([np.ones_like(x), x, y, z, x * x, x * y, y * y])


@dataclass(frozen=True, slots=True)
class PositionCorrection:
    """error(p) = reached - commanded, one row of ``FEATURES`` coefficients per axis (x, y, z)."""

    coefficients: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]
    rms_before_m: float = 0.0
    rms_after_m: float = 0.0
    max_after_m: float = 0.0
    pairs: int = 0

    def error_at(self, points: FloatArray) -> FloatArray:
        """Predicted reached-minus-commanded error (n, 3) at commanded points (n, 3)."""
        coefficients = np.asarray(self.coefficients, dtype=np.float64)
        return np.asarray(_features(np.atleast_2d(points)) @ coefficients.T, dtype=np.float64)

    def correct(self, target: Sequence[float], *, iterations: int = 4) -> tuple[float, float, float]:
        """The point to command so that the gripper reaches ``target``."""
        goal = np.asarray(target, dtype=np.float64)
        command = goal.copy()
        for _ in range(iterations):
            command = goal - self.error_at(command[None, :])[0]
        return float(command[0]), float(command[1]), float(command[2])

    def to_mapping(self) -> dict[str, object]:
        return {
            "features": list(FEATURES),
            "x": list(self.coefficients[0]),
            "y": list(self.coefficients[1]),
            "z": list(self.coefficients[2]),
            "rms_before_m": self.rms_before_m,
            "rms_after_m": self.rms_after_m,
            "max_after_m": self.max_after_m,
            "pairs": self.pairs,
        }

    @classmethod
    def from_mapping(cls, data: Mapping[str, object], *, source: str = "calibration") -> PositionCorrection:
        """Read a stored correction; raises ``CalibrationError`` naming the bad field."""
        features = data.get("features")
        if not isinstance(features, list) or features != list(FEATURES):
            raise CalibrationError(f"{source}: features must be {list(FEATURES)}")
        rows = []
        for axis in ("x", "y", "z"):
            raw = data.get(axis)
            if not isinstance(raw, list) or len(raw) != len(FEATURES):
                raise CalibrationError(f"{source}: {axis} must be {len(FEATURES)} finite numbers")
            try:
                row = tuple(float(v) for v in raw)
            except (TypeError, ValueError) as e:
                raise CalibrationError(f"{source}: {axis} must be {len(FEATURES)} finite numbers") from e
            if not all(math.isfinite(v) for v in row):
                raise CalibrationError(f"{source}: {axis} must be {len(FEATURES)} finite numbers")
            rows.append(row)
        return cls((rows[0], rows[1], rows[2]))

    @classmethod
    def load(cls, path: Path) -> PositionCorrection:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except OSError as e:
            raise CalibrationError(f"cannot read the calibration file {path}: {e.strerror}") from e
        except json.JSONDecodeError as e:
            raise CalibrationError(f"{path} is not JSON: {e.msg} at line {e.lineno}") from e
        if not isinstance(data, dict):
            raise CalibrationError(f"{path}: expected a JSON object")
        return cls.from_mapping(data, source=str(path))


def fit_correction(
    commanded: Sequence[Sequence[float]] | FloatArray, reached: Sequence[Sequence[float]] | FloatArray
) -> PositionCorrection:
    """Least-squares fit of the reached-minus-commanded error; needs at least 14 well-spread pairs."""
    try:
        c = np.asarray(commanded, dtype=np.float64)
        r = np.asarray(reached, dtype=np.float64)
    except ValueError as e:
        raise CalibrationError("calibration pairs must be lists of [x, y, z] numbers") from e
    if c.ndim != 2 or c.shape[1:] != (3,) or r.shape != c.shape:
        raise CalibrationError(
            f"calibration pairs must be matching lists of [x, y, z]; got {list(c.shape)} commanded and "
            f"{list(r.shape)} reached"
        )
    if len(c) < _MIN_PAIRS:
        raise CalibrationError(f"need at least {_MIN_PAIRS} calibration pairs, got {len(c)}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
        raise CalibrationError("calibration pairs must be finite numbers")
    design = _features(c)
    if np.linalg.matrix_rank(design) < len(FEATURES):
        raise CalibrationError(
            "calibration points are degenerate: spread them over x, y and at least two heights"
        )
    error = r - c
    coefficients, *_ = np.linalg.lstsq(design, error, rcond=None)
    residual = error - design @ coefficients
    before = np.linalg.norm(error, axis=1)
    after = np.linalg.norm(residual, axis=1)
    rows = tuple(tuple(float(v) for v in coefficients[:, i]) for i in range(3))
    return PositionCorrection(
        (rows[0], rows[1], rows[2]),
        rms_before_m=float(np.sqrt(np.mean(before**2))),
        rms_after_m=float(np.sqrt(np.mean(after**2))),
        max_after_m=float(np.max(after)),
        pairs=len(c),
    )


def load_pairs(path: Path) -> tuple[list[list[float]], list[list[float]]]:
    """Read ``{"pairs": [{"commanded": [x, y, z], "reached": [x, y, z]}, ...]}``."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise CalibrationError(f"cannot read {path}: {e.strerror}") from e
    except json.JSONDecodeError as e:
        raise CalibrationError(f"{path} is not JSON: {e.msg} at line {e.lineno}") from e
    pairs = data.get("pairs") if isinstance(data, dict) else None
    if not isinstance(pairs, list):
        raise CalibrationError(
            f'{path}: expected {{"pairs": [{{"commanded": [x, y, z], "reached": [x, y, z]}}]}}'
        )
    commanded, reached = [], []
    for i, pair in enumerate(pairs):
        if not isinstance(pair, dict) or "commanded" not in pair or "reached" not in pair:
            raise CalibrationError(f"{path}: pairs[{i}] needs 'commanded' and 'reached'")
        commanded.append(pair["commanded"])
        reached.append(pair["reached"])
    return commanded, reached
