"""Trajectories within each servo's speed and acceleration limits, sampled at the control rate."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import PchipInterpolator

from planning.interfaces import MotionRefused
from planning.motion import plan_path
from planning.motion.trajectory import Trapezoid, _Pchip, _Straight

NAMES = ("a", "b", "c")
VMAX = np.array([1.0, 2.0, 0.5])
AMAX = np.array([2.0, 4.0, 1.0])


def _plan(waypoints: object, rate: float = 50.0) -> tuple[np.ndarray, np.ndarray]:
    traj, _ = plan_path(
        np.asarray(waypoints, dtype=float),
        names=NAMES,
        max_velocity=VMAX,
        max_acceleration=AMAX,
        rate_hz=rate,
        label="t",
    )
    return traj.times, traj.positions


def _check_limits(times: np.ndarray, q: np.ndarray, slack: float = 1.02) -> None:
    dt = np.diff(times)
    v = np.diff(q, axis=0) / dt[:, None]
    assert np.all(np.abs(v) <= VMAX * slack)
    if len(dt) > 2:
        a = np.diff(v[:-1], axis=0) / dt[1:-1, None]
        assert np.all(np.abs(a) <= AMAX * slack * 1.03)


def test_trapezoid_reaches_the_end_at_rest() -> None:
    for profile in (Trapezoid(0.5, 1.0), Trapezoid(10.0, 1.0)):
        s, sd, _ = profile.at(np.array([0.0, profile.duration]))
        assert s.tolist() == pytest.approx([0.0, 1.0])
        assert sd.tolist() == pytest.approx([0.0, 0.0], abs=1e-12)


def test_trapezoid_durations_match_the_closed_form() -> None:
    # Triangle: peak never reached, T = 2 sqrt(1 / a).
    assert Trapezoid(10.0, 4.0).duration == pytest.approx(1.0)
    # Trapezoid: T = 1 / v + v / a.
    assert Trapezoid(0.5, 1.0).duration == pytest.approx(2.5)


def test_the_slowest_joint_sets_the_pace_of_a_joint_move() -> None:
    times, q = _plan([[0.0, 0.0, 0.0], [0.1, 0.1, 1.0]])
    # Joint c moves 1 rad at 0.5 rad/s and 1 rad/s²: 1/0.5 + 0.5/1 = 2.5 s.
    assert times[-1] == pytest.approx(2.5, rel=1e-6)
    assert np.allclose(q[-1], [0.1, 0.1, 1.0])
    # Every joint starts and ends together on a straight line in joint space.
    ratios = (q - q[0]) / np.array([0.1, 0.1, 1.0])
    assert np.allclose(ratios[:, 0], ratios[:, 2])


def test_samples_are_at_the_control_rate_with_the_exact_end() -> None:
    times, _ = _plan([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]], rate=100.0)
    assert np.allclose(np.diff(times)[:-1], 0.01)
    assert times[0] == 0.0


def test_a_path_through_waypoints_stays_within_limits_and_passes_them() -> None:
    waypoints = np.array([[0.0, 0.0, 0.0], [0.3, 0.5, 0.2], [0.6, 0.4, 0.5], [0.9, 0.0, 0.6]])
    times, q = _plan(waypoints)
    _check_limits(times, q)
    # PCHIP never overshoots the waypoints' range.
    assert np.all(q.min(axis=0) >= waypoints.min(axis=0) - 1e-9)
    assert np.all(q.max(axis=0) <= waypoints.max(axis=0) + 1e-9)


def test_staying_put_is_a_single_sample() -> None:
    times, q = _plan([[0.2, 0.2, 0.2], [0.2, 0.2, 0.2]])
    assert times.tolist() == [0.0]
    assert q.tolist() == [[0.2, 0.2, 0.2]]


def test_a_nan_waypoint_is_refused() -> None:
    with pytest.raises(MotionRefused, match=r"^t: a waypoint is not finite$"):
        _plan([[0.0, 0.0, 0.0], [math.nan, 0.0, 0.0]])


def test_a_waypoint_of_the_wrong_size_is_refused() -> None:
    with pytest.raises(MotionRefused, match=r"^t: waypoints must be a non-empty list of 3 joint angles$"):
        _plan([[0.0, 0.0], [1.0, 0.0]])


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    st.lists(st.tuples(*(st.floats(-2.0, 2.0, allow_nan=False) for _ in range(3))), min_size=2, max_size=6)
)
def test_any_path_respects_speed_and_acceleration_limits(points: list[tuple[float, float, float]]) -> None:
    times, q = _plan(points)
    assert np.allclose(q[0], points[0], atol=1e-9)
    assert np.allclose(q[-1], points[-1], atol=1e-9)
    if len(times) > 1:
        _check_limits(times, q)


@settings(max_examples=200, deadline=None)
@given(
    start=st.lists(st.floats(-3.0, 3.0), min_size=5, max_size=5),
    step=st.lists(st.floats(-2.0, 2.0) | st.just(0.0), min_size=5, max_size=5),
)
def test_a_two_waypoint_path_is_the_pchip_scipy_builds_to_the_last_bit(
    start: list[float], step: list[float]
) -> None:
    """A joint move's path (two waypoints) skips building scipy's interpolator: the same numbers."""
    a = np.array(start)
    b = a + np.array(step)
    pchip = PchipInterpolator(np.array([0.0, 1.0]), np.array([a, b]), axis=0)
    straight = _Straight(a, b)
    s = np.concatenate([np.linspace(0.0, 1.0, 97), [1e-300, 0.5 + 1e-16]])
    for nu, ours in enumerate(straight.at(s)):
        assert ours.tobytes() == np.asarray(pchip(s, nu)).tobytes()


@settings(max_examples=300, deadline=None)
@given(
    rows=st.lists(
        st.lists(st.floats(-3.0, 3.0).map(lambda v: round(v, 6)) | st.just(1.0), min_size=5, max_size=5),
        min_size=3,
        max_size=9,
    ),
    gaps=st.lists(st.floats(1e-3, 1.0), min_size=8, max_size=8),
)
def test_a_path_of_three_or_more_waypoints_is_the_pchip_scipy_builds_to_the_last_bit(
    rows: list[list[float]], gaps: list[float]
) -> None:
    """A Cartesian move's path (many waypoints, flat, turning and repeated joints among them) is scipy's
    PCHIP without SciPy: the same numbers at the knots, between them and past both ends."""
    waypoints = np.array(rows)
    knots = np.concatenate([[0.0], np.cumsum(gaps[: len(rows) - 1])])
    knots /= knots[-1]
    pchip = PchipInterpolator(knots, waypoints, axis=0)
    s = np.concatenate([np.linspace(-0.1, 1.1, 131), knots, knots + 1e-16, [1e-300, 0.5 + 1e-16]])
    for nu, ours in enumerate(_Pchip(knots, waypoints).at(s)):
        assert ours.tobytes() == np.asarray(pchip(s, nu)).tobytes()


def test_the_motion_planner_and_its_paths_load_no_scipy() -> None:
    """Every process that plans (the daemon, its planning worker) would pay SciPy's import, 0.4 s of CPU."""
    probe = (
        "import sys, numpy as np\n"
        "from planning.motion import CyclePlanner, plan_path\n"
        "plan_path(np.array([[0.0, 0.0], [0.5, 0.2], [1.0, 0.1]]), names=('a', 'b'),\n"
        "          max_velocity=np.ones(2), max_acceleration=np.ones(2), rate_hz=50.0, label='t')\n"
        "print(sorted(m for m in sys.modules if m.partition('.')[0] == 'scipy'))\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
