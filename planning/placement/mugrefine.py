"""How close the tray is to holding one more mug: the largest clearance found for a layout with one more.

``dishbot bench placement --one-more`` asks this per dataset (issue 24: dataset 1 plans 11 of its 12 mugs).
The planner packs the same mugs with smaller clearances (the problem's less 1 mm, 2 mm, ...) until it places
more than it does with the problem's own; that layout is a start for ``refine``, which moves the brim
centres freely (off the packer's 2 mm grid; each handle turning with its brim's bearing, as the arm turns
it) to make the least gap between two outlines, and twice the least gap to a wall, as large as it can
(SLSQP from scipy; the gaps are the packer's exact distances from ``shapes``, their derivatives taken by
finite differences, all positions at once). A result at or above the problem's clearance would be a valid
layout with one more mug; below it, it says by how much the search missed (a local optimum, not a bound).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize

from planning.placement.context import PlanOptions
from planning.placement.planner import plan
from planning.placement.problem import Problem
from planning.placement.shapes import MugOutline, point_segment, segment_segment

FloatArray = npt.NDArray[np.float64]
_STEP_MM = 1e-4  # finite-difference step


@dataclass(frozen=True)
class Refined:
    """The brim centres after the search (tray mm, same order) and the clearance they keep: the least gap
    between two outlines and twice the least gap to a wall."""

    brims: tuple[tuple[float, float], ...]
    clearance: float
    iterations: int


class _Layout:
    """The mugs' outlines as arrays, evaluated for many position vectors at once."""

    def __init__(self, problem: Problem, mugs: Sequence[tuple[str, float]]) -> None:
        outlines = [MugOutline.of(problem.mug_types[t]) for t, _ in mugs]
        self.r = np.array([o.radius for o in outlines])
        self.h0 = np.array([o.handle_from for o in outlines])
        self.h1 = np.array([o.handle_to for o in outlines])
        self.t = np.array([o.half_thickness for o in outlines])
        self.rel = np.array([rel for _, rel in mugs])
        self.origin = np.subtract(problem.tray_origin_mm, problem.arm_base_mm)
        self.size = problem.tray_size_mm
        n = len(mugs)
        self.i, self.j = np.triu_indices(n, 1)

    def gaps(self, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``xy`` (..., n, 2): the gaps of every pair (..., n (n - 1) / 2) and to the walls (..., n)."""
        cx, cy = xy[..., 0], xy[..., 1]
        yaw = np.arctan2(cy + self.origin[1], cx + self.origin[0]) + self.rel
        c, s = np.cos(yaw), np.sin(yaw)
        ax, ay = cx + self.h0 * c, cy + self.h0 * s
        bx, by = cx + self.h1 * c, cy + self.h1 * s
        i, j = self.i, self.j
        discs = np.hypot(cx[..., i] - cx[..., j], cy[..., i] - cy[..., j]) - self.r[i] - self.r[j]
        pairs = np.minimum.reduce(
            [
                discs,
                point_segment(cx[..., j], cy[..., j], ax[..., i], ay[..., i], bx[..., i], by[..., i])
                - self.t[i]
                - self.r[j],
                point_segment(cx[..., i], cy[..., i], ax[..., j], ay[..., j], bx[..., j], by[..., j])
                - self.t[j]
                - self.r[i],
                segment_segment(
                    ax[..., i],
                    ay[..., i],
                    bx[..., i],
                    by[..., i],
                    ax[..., j],
                    ay[..., j],
                    bx[..., j],
                    by[..., j],
                )
                - self.t[i]
                - self.t[j],
            ]
        )
        tx, ty = self.size
        disc = np.minimum.reduce([cx - self.r, tx - cx - self.r, cy - self.r, ty - cy - self.r])
        bar = np.minimum.reduce(
            [
                np.minimum(ax, bx) - self.t,
                tx - np.maximum(ax, bx) - self.t,
                np.minimum(ay, by) - self.t,
                ty - np.maximum(ay, by) - self.t,
            ]
        )
        return np.asarray(pairs, np.float64), np.asarray(np.minimum(disc, bar), np.float64)


def clearance_of(problem: Problem, mugs: Sequence[tuple[str, float]], brims: FloatArray) -> float:
    """The least gap between two outlines and twice the least gap to a wall (``brims``: (n, 2))."""
    pairs, walls = _Layout(problem, mugs).gaps(np.asarray(brims, np.float64))
    return float(min(pairs.min(initial=math.inf), 2.0 * walls.min(initial=math.inf)))


def refine(
    problem: Problem,
    mugs: Sequence[tuple[str, float]],
    brims: Sequence[tuple[float, float]],
    *,
    max_iterations: int = 200,
) -> Refined:
    """Moves the brims (tray mm; ``mugs``: type and handle angle to the slot's bearing, ``Problem.
    relative_yaw``) to keep as large a clearance as it can find; never returns less than the start's."""
    lay = _Layout(problem, mugs)
    n = len(mugs)
    start = np.asarray(brims, np.float64).reshape(n, 2)
    pairs, walls = lay.gaps(start)
    s0 = float(min(pairs.min(initial=math.inf), 2.0 * walls.min(initial=math.inf)))
    # Variables: the brims (2n) and s. Constraints: pair gaps - s >= 0, wall gaps - s / 2 >= 0.
    m = len(lay.i)

    def values(z: FloatArray) -> FloatArray:
        p, w = lay.gaps(z[:, :-1].reshape(-1, n, 2))
        return np.concatenate([p - z[:, -1:], w - z[:, -1:] / 2.0], axis=-1)

    def fun(z: FloatArray) -> FloatArray:
        return np.asarray(values(z[None, :])[0], np.float64)

    def jac(z: FloatArray) -> FloatArray:
        batch = np.repeat(z[None, :], 2 * n + 1, axis=0)
        batch[1:, : 2 * n] += _STEP_MM * np.eye(2 * n)
        v = values(batch)
        d = (v[1:] - v[0]) / _STEP_MM  # (2n, constraints)
        ds = np.concatenate([-np.ones(m), -0.5 * np.ones(n)])
        return np.concatenate([d.T, ds[:, None]], axis=1)

    best = (s0, start, 0)
    z = np.concatenate([start.ravel(), [s0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = minimize(
            lambda z: -z[-1],
            z,
            jac=lambda z: np.concatenate([np.zeros(2 * n), [-1.0]]),
            constraints=[{"type": "ineq", "fun": fun, "jac": jac}],
            method="SLSQP",
            options={"maxiter": max_iterations, "ftol": 1e-9},
        )
    xy = np.asarray(res.x[:-1], np.float64).reshape(n, 2)
    pairs, walls = lay.gaps(xy)
    s = float(min(pairs.min(initial=math.inf), 2.0 * walls.min(initial=math.inf)))
    if s > best[0]:
        best = (s, xy, int(res.nit))
    return Refined(tuple((float(x), float(y)) for x, y in best[1]), best[0], best[2])


@dataclass(frozen=True)
class OneMore:
    """A layout of ``count`` mugs (one more than the problem's plan) found with the planner at ``packed_at``
    mm of clearance, then refined: it keeps ``clearance`` mm (``Refined``); ``mugs`` as for ``refine``."""

    count: int
    packed_at: int
    mugs: tuple[tuple[str, float], ...]
    refined: Refined


def one_more(problem: Problem, planned: int, *, options: PlanOptions, lowest_mm: int = 0) -> OneMore | None:
    """The first layout with more than ``planned`` mugs that the planner packs at a clearance below the
    problem's (1 mm less each time, down to ``lowest_mm``), refined under the problem's clearance; None
    when no clearance down to ``lowest_mm`` packs more (or there is nothing more to place)."""
    if planned >= len(problem.mugs):
        return None
    for tolerance in range(problem.tolerance_mm - 1, lowest_mm - 1, -1):
        result = plan(replace(problem, tolerance_mm=tolerance), options)
        if result.n <= planned:
            continue
        index = {m.id: i for i, m in enumerate(problem.mugs)}
        mugs = tuple((p.type, problem.relative_yaw(index[p.id])) for p in result.placed)
        brims = [p.brim_mm for p in result.placed if p.brim_mm is not None]
        return OneMore(result.n, tolerance, mugs, refine(problem, mugs, brims))
    return None
