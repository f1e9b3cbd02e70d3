"""Joint-space trajectories within each servo's speed and acceleration limits, sampled at the control rate.

A path is a list of joint waypoints (two for a plain joint move, many for a Cartesian line or arc solved by
IK). It is interpolated by a shape-preserving cubic (PCHIP: no joint overshoots its waypoints, so a path
whose waypoints are inside the limits stays inside) over a path parameter s in [0, 1], and s follows a
trapezoidal speed profile whose peak speed and acceleration are the largest every joint allows all along
the path: |q'(s)| s_dot <= v_max and |q'(s)| s_ddot + |q''(s)| s_dot^2 <= a_max. The sampled result is checked
by finite differences and slowed down uniformly if the bound was not met.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.interfaces import FloatArray, JointTrajectory
from planning.interfaces import MotionRefused

_GRID = 256
_LIMIT_SLACK = 1.02


@dataclass(frozen=True, slots=True)
class Trapezoid:
    """s(t) from 0 to 1 with peak speed ``v`` and acceleration ``a`` (triangular if ``v`` is not reached)."""

    v: float
    a: float

    @property
    def accel_time(self) -> float:
        return min(self.v / self.a, math.sqrt(1.0 / self.a))

    @property
    def duration(self) -> float:
        ta = self.accel_time
        peak = self.a * ta
        cruise = max(0.0, 1.0 - peak * ta) / peak
        return 2 * ta + cruise

    def at(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """s, s_dot, s_ddot at times ``t`` (clipped to [0, duration])."""
        ta = self.accel_time
        peak = self.a * ta
        total = self.duration
        t = np.clip(t, 0.0, total)
        s = np.empty_like(t)
        sd = np.empty_like(t)
        sdd = np.zeros_like(t)
        rising = t < ta
        falling = t > total - ta
        cruise = ~(rising | falling)
        s[rising] = 0.5 * self.a * t[rising] ** 2
        sd[rising] = self.a * t[rising]
        sdd[rising] = self.a
        s[cruise] = 0.5 * peak * ta + peak * (t[cruise] - ta)
        sd[cruise] = peak
        rest = total - t[falling]
        s[falling] = 1.0 - 0.5 * self.a * rest**2
        sd[falling] = self.a * rest
        sdd[falling] = -self.a
        return s, sd, sdd


class _Straight:
    """The PCHIP through two waypoints over s in [0, 1], a straight segment: the numbers scipy's
    ``PchipInterpolator`` gives there (its cubic and quadratic coefficients are exactly zero, and it
    evaluates the start plus the slope times s), without building one (a joint move's path is two
    waypoints, and building the interpolator cost more than timing the whole move)."""

    def __init__(self, start: FloatArray, end: FloatArray) -> None:
        slope = end - start  # (end - start) / 1.0, the knots being 0 and 1
        self._start = 0.0 + start
        self._slope = 0.0 + slope

    def at(self, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Positions and their first and second derivatives in s at ``s``, each (len(s), n_joints)."""
        q = np.asarray(self._start[None, :] + self._slope[None, :] * s[:, None], dtype=np.float64)
        return q, np.repeat(self._slope[None, :], len(s), axis=0), np.zeros((len(s), len(self._slope)))


class _Pchip:
    """The PCHIP through three or more waypoints over increasing knots: the numbers scipy's
    ``PchipInterpolator`` gives (its derivatives at the knots, its cubic coefficients and its evaluation of
    the ``nu``-th derivative, operation for operation), without importing SciPy, which took 0.4 s of every
    process that plans (the daemon and its planning worker) for this one interpolator."""

    def __init__(self, knots: FloatArray, waypoints: FloatArray) -> None:
        x = knots[:, None]
        y = waypoints
        dx = np.diff(knots)[:, None]
        dydx = _pchip_derivatives(x, y)
        slope = np.diff(y, axis=0) / dx
        t = (dydx[:-1] + dydx[1:] - 2 * slope) / dx
        self._inner = np.ascontiguousarray(knots[1:-1])
        self._starts = np.ascontiguousarray(knots[:-1])
        # Segment i's cubic is c3 + c2 h + c1 h^2 + c0 h^3 in h = s - knots[i] (scipy's PPoly coefficients);
        # scipy sums each derivative's terms starting from 0.0, so the first term of each sum is kept
        # with it added (which only turns a -0.0 into 0.0).
        c0 = t / dx
        c1 = (slope - dydx[:-1]) / dx - t
        self._c0, self._c1, self._c2 = c0, c1, np.ascontiguousarray(dydx[:-1])
        self._first = (0.0 + y[:-1], 0.0 + self._c2, 0.0 + c1 * 2.0)

    def at(self, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Positions and their first and second derivatives in s at ``s``, each (len(s), n_joints): the
        segment as scipy finds it (the last one holds the right end; outside, the end segments extend),
        then scipy's sum of coefficient times power times the derivative's factor, term by term."""
        segment = np.searchsorted(self._inner, s, side="right")
        h = (s - self._starts.take(segment))[:, None]
        h2 = h * h
        c0, c1, c2 = (c.take(segment, axis=0) for c in (self._c0, self._c1, self._c2))
        first0, first1, first2 = (f.take(segment, axis=0) for f in self._first)
        q: FloatArray = first0 + c2 * h + c1 * h2 + c0 * (h2 * h)
        dq: FloatArray = first1 + c1 * h * 2.0 + c0 * h2 * 3.0
        ddq: FloatArray = first2 + c0 * h * 6.0
        return q, dq, ddq


def _pchip_derivatives(x: FloatArray, y: FloatArray) -> FloatArray:
    """The PCHIP's slope at every knot (``x`` a column): zero where the neighbouring segments' slopes differ
    in sign or one is flat, else their weighted harmonic mean; a shape-preserving three-point estimate at
    each end (scipy's ``PchipInterpolator._find_derivatives``, the same operations)."""
    hk = x[1:] - x[:-1]
    mk = (y[1:] - y[:-1]) / hk
    smk = np.sign(mk)
    condition = (smk[1:] != smk[:-1]) | (mk[1:] == 0) | (mk[:-1] == 0)
    w1 = 2 * hk[1:] + hk[:-1]
    w2 = hk[1:] + 2 * hk[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):  # where it divides by zero, ``condition`` holds
        whmean = (w1 / mk[:-1] + w2 / mk[1:]) / (w1 + w2)
    dk = np.zeros_like(y)
    dk[1:-1][~condition] = 1.0 / whmean[~condition]
    dk[0] = _pchip_end(hk[0], hk[1], mk[0], mk[1])
    dk[-1] = _pchip_end(hk[-1], hk[-2], mk[-1], mk[-2])
    return dk


def _pchip_end(h0: FloatArray, h1: FloatArray, m0: FloatArray, m1: FloatArray) -> FloatArray:
    """The slope at an end knot: the one-sided three-point estimate, zero when its sign is not the end
    segment's, three times the end segment's slope when the next one turns and it overshoots."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    flipped = np.sign(d) != np.sign(m0)
    overshoots = (np.sign(m0) != np.sign(m1)) & (np.abs(d) > 3.0 * np.abs(m0))
    d[flipped] = 0.0
    d[~flipped & overshoots] = 3.0 * m0[~flipped & overshoots]
    return d


class JointPath:
    """A time-parameterised joint path that can be evaluated at any time (for sampling and checking)."""

    def __init__(
        self,
        waypoints: FloatArray,
        max_velocity: FloatArray,
        max_acceleration: FloatArray,
        *,
        tool_path_length_m: float = 0.0,
        max_tool_speed_m_s: float = math.inf,
    ) -> None:
        self.waypoints = _dedupe(np.asarray(waypoints, dtype=np.float64))
        self.max_velocity = max_velocity
        self.max_acceleration = max_acceleration
        n = len(self.waypoints)
        if n == 1:
            self._spline: _Pchip | _Straight | None = None
            self.profile = Trapezoid(1.0, 1.0)
            self.duration = 0.0
            return
        steps = np.max(np.abs(np.diff(self.waypoints, axis=0)) / max_velocity, axis=1)
        knots = np.concatenate([[0.0], np.cumsum(steps)])
        knots /= knots[-1]
        if n == 2:
            self._spline = _Straight(self.waypoints[0], self.waypoints[1])
        else:
            self._spline = _Pchip(knots, self.waypoints)
        grid = np.union1d(np.linspace(0.0, 1.0, _GRID), knots)
        _, d1, d2 = self._spline.at(grid)
        d1, d2 = np.abs(d1), np.abs(d2)
        with np.errstate(divide="ignore"):
            v = float(np.min(max_velocity / np.maximum(d1, 1e-12)))
            v = min(v, float(np.min(np.sqrt(0.5 * max_acceleration / np.maximum(d2, 1e-12)))))
            if tool_path_length_m > 0 and math.isfinite(max_tool_speed_m_s):
                v = min(v, max_tool_speed_m_s / tool_path_length_m)
            a = float(np.min((max_acceleration - d2 * v * v) / np.maximum(d1, 1e-12)))
        self.profile = Trapezoid(v, a)
        self.duration = self.profile.duration

    def state_at(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Positions, velocities and accelerations (len(t), n_joints) at times ``t``."""
        if self._spline is None:
            q = np.repeat(self.waypoints[:1], len(t), axis=0)
            return q, np.zeros_like(q), np.zeros_like(q)
        s, sd, sdd = self.profile.at(t)
        q, d1, d2 = self._spline.at(s)
        return q, d1 * sd[:, None], d2 * (sd**2)[:, None] + d1 * sdd[:, None]

    def slowed(self, factor: float) -> None:
        """Stretch time by ``factor`` (> 1): speeds divide by it, accelerations by its square."""
        self.profile = Trapezoid(self.profile.v / factor, self.profile.a / factor**2)
        self.duration = self.profile.duration

    def sample_times(self, rate_hz: float) -> FloatArray:
        """0, 1/rate, 2/rate, ... and the exact end time."""
        if self.duration == 0.0:
            return np.zeros(1)
        n = math.floor(self.duration * rate_hz + 1e-9)
        times = np.arange(n + 1) / rate_hz
        if self.duration - times[-1] > 1e-9:
            times = np.append(times, self.duration)
        return times


def plan_path(
    waypoints: Sequence[Sequence[float]] | FloatArray,
    *,
    names: tuple[str, ...],
    max_velocity: FloatArray,
    max_acceleration: FloatArray,
    rate_hz: float,
    label: str,
    tool_path_length_m: float = 0.0,
    max_tool_speed_m_s: float = math.inf,
) -> tuple[JointTrajectory, JointPath]:
    """Time-parameterise a joint path and sample it at ``rate_hz``; returns the trajectory and its path
    (kept for collision checking at finer steps and for the energy model)."""
    arr = np.asarray(waypoints, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != len(names) or len(arr) == 0:
        raise MotionRefused(f"{label}: waypoints must be a non-empty list of {len(names)} joint angles")
    if not np.all(np.isfinite(arr)):
        raise MotionRefused(f"{label}: a waypoint is not finite")
    if not rate_hz > 0:
        raise MotionRefused(f"{label}: control rate must be > 0 Hz, got {rate_hz}")
    path = JointPath(
        arr,
        max_velocity,
        max_acceleration,
        tool_path_length_m=tool_path_length_m,
        max_tool_speed_m_s=max_tool_speed_m_s,
    )
    for _ in range(8):
        times = path.sample_times(rate_hz)
        q, _, _ = path.state_at(times)
        worst = _worst_limit_ratio(times, q, max_velocity, max_acceleration)
        if worst <= _LIMIT_SLACK:
            break
        path.slowed(math.sqrt(worst) if worst > 1 else 1.05)
    else:
        raise MotionRefused(f"{label}: could not keep the trajectory within the servo limits")
    return JointTrajectory(names=names, times=times, positions=q, label=label), path


def _worst_limit_ratio(times: FloatArray, q: FloatArray, vmax: FloatArray, amax: FloatArray) -> float:
    """Largest ratio of finite-difference speed or acceleration to its limit over all samples and joints."""
    if len(times) < 2:
        return 0.0
    dt = np.diff(times)[:, None]
    v = np.diff(q, axis=0) / dt
    worst = float(np.max(np.abs(v) / vmax))
    if len(times) >= 3:
        mid_dt = (dt[1:] + dt[:-1]) / 2
        a = np.diff(v, axis=0) / mid_dt
        # The last interval may be short; its second difference overstates a smooth stop.
        worst = max(worst, float(np.max(np.abs(a[:-1]) / amax)) if len(a) > 1 else 0.0)
    return worst


def _dedupe(waypoints: FloatArray) -> FloatArray:
    """Drop consecutive duplicate waypoints (a zero-length step would break the path parameter). Most paths
    have none: when every step moves more than the tolerance, each waypoint's kept predecessor is the one
    before it and all are kept, which one vectorised test shows."""
    if len(waypoints) < 2 or bool(np.all(np.max(np.abs(np.diff(waypoints, axis=0)), axis=1) > 1e-9)):
        return waypoints.copy()
    keep = [0]
    for i in range(1, len(waypoints)):
        if float(np.max(np.abs(waypoints[i] - waypoints[keep[-1]]))) > 1e-9:
            keep.append(i)
    return waypoints[keep]
