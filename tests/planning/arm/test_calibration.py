"""Fitting and applying the position correction (appendix A's idea as a general tool)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from description import thesis
from planning.arm import CalibrationError
from planning.arm.calibration import PositionCorrection, fit_correction, load_pairs


def _thesis_like_arm(commanded: np.ndarray) -> np.ndarray:
    """A 'real arm' whose reached point drifts like the thesis's Eq A.1-A.3 models, scaled to a few cm."""
    x, y = commanded[:, 0], commanded[:, 1]
    feats = np.column_stack([np.ones_like(x), x, np.abs(y), x * x, x * np.abs(y), y * y])
    fx = feats @ np.asarray(thesis.THESIS_ERROR_FIT_X) - x
    fy = np.sign(y) * (feats @ np.asarray(thesis.THESIS_ERROR_FIT_Y) - np.abs(y))
    fz = feats @ np.asarray(thesis.THESIS_ERROR_FIT_Z)
    return commanded + 0.1 * np.column_stack([fx, fy, fz])


def _grid(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(0.35, 0.65, n), rng.uniform(0.05, 0.5, n), rng.choice([0.06, 0.2], n)]
    )


def test_correction_brings_a_drifting_arm_to_within_a_few_millimetres() -> None:
    commanded = _grid(1, 60)
    correction = fit_correction(commanded, _thesis_like_arm(commanded))
    assert correction.rms_before_m > 0.005
    targets = _grid(2, 30)
    corrected = np.array([correction.correct(t) for t in targets])
    errors = np.linalg.norm(_thesis_like_arm(corrected) - targets, axis=1)
    assert float(np.max(errors)) < 0.003


def test_exact_quadratic_errors_are_recovered_exactly() -> None:
    commanded = _grid(3, 40)
    x, y = commanded[:, 0], commanded[:, 1]
    reached = commanded + np.column_stack([0.01 + 0.02 * x * y, -0.005 * y, 0.003 * x])
    correction = fit_correction(commanded, reached)
    assert correction.rms_after_m < 1e-9
    assert correction.coefficients[0][5] == pytest.approx(0.02)


def test_stored_correction_reads_back_equal(tmp_path: Path) -> None:
    commanded = _grid(4, 20)
    correction = fit_correction(commanded, commanded + 0.001)
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(correction.to_mapping()), encoding="utf-8")
    loaded = PositionCorrection.load(path)
    assert loaded.coefficients == correction.coefficients


def test_too_few_pairs_are_refused() -> None:
    with pytest.raises(CalibrationError, match=r"^need at least 14 calibration pairs, got 3$"):
        fit_correction(_grid(5, 3), _grid(5, 3))


def test_pairs_on_one_line_are_refused_as_degenerate() -> None:
    line = np.column_stack([np.linspace(0.3, 0.6, 20), np.zeros(20), np.full(20, 0.06)])
    with pytest.raises(CalibrationError, match=r"^calibration points are degenerate: spread them over x, y"):
        fit_correction(line, line)


def test_nan_pairs_are_refused() -> None:
    bad = _grid(6, 20)
    bad[3, 1] = math.nan
    with pytest.raises(CalibrationError, match=r"^calibration pairs must be finite numbers$"):
        fit_correction(bad, _grid(6, 20))


def test_mismatched_pairs_are_refused() -> None:
    with pytest.raises(CalibrationError, match=r"^calibration pairs must be matching lists of \[x, y, z\]"):
        fit_correction(_grid(7, 20), _grid(7, 19))


def test_a_stored_correction_with_a_missing_axis_is_refused() -> None:
    data = fit_correction(_grid(8, 20), _grid(8, 20)).to_mapping()
    del data["y"]
    with pytest.raises(CalibrationError, match=r"^calibration: y must be 7 finite numbers$"):
        PositionCorrection.from_mapping(data)


def test_pairs_file_without_pairs_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "pairs.json"
    path.write_text('{"points": []}', encoding="utf-8")
    with pytest.raises(CalibrationError, match=r'pairs.json: expected \{"pairs": '):
        load_pairs(path)
