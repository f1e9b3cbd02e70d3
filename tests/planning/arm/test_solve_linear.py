"""The IK's linear solve: numpy's LAPACK routine where numpy has it, ``np.linalg.solve`` otherwise, the same
numbers either way."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from planning.arm import model


@given(st.integers(0, 2**32 - 1))
def test_the_fast_solve_equals_numpys_on_damped_normal_equations(seed: int) -> None:
    rng = np.random.default_rng(seed)
    j = rng.normal(size=(6, 5))
    a = j.T @ j + 1e-3 * np.eye(5)  # as the solver builds it: damped, positive definite
    b = rng.normal(size=5)
    assert np.array_equal(model._solve_linear(a, b), np.linalg.solve(a, b))


def test_without_numpys_private_routine_the_solve_falls_back_to_the_public_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(model, "_SOLVE1", None)
    a = np.array([[4.0, 1.0], [1.0, 3.0]])
    b = np.array([1.0, 2.0])
    assert np.allclose(model._solve_linear(a, b), [1.0 / 11.0, 7.0 / 11.0])
