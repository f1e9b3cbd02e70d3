"""How close the tray is to holding one more mug: the largest clearance found for a layout with one more.

``dishbot bench placement --one-more`` asks this per dataset (issue 24: dataset 1 plans 11 of its 12 mugs).
The planner packs the same mugs with smaller clearances (the problem's less 1 mm, 2 mm, ...) until it places
more than it does with the problem's own; that layout is a start for ``refine``, which moves the brim
centres freely (off the packer's 2 mm grid, each within ``REACH_MM`` of its start; each handle turning with
its brim's bearing, as the arm turns it) to make the least gap between two outlines, and twice the least
gap to a wall, as large as it can (SLSQP from scipy; the gaps are the packer's exact distances from
``shapes``, each smooth piece of each a constraint of its own, their derivatives taken by finite differences
for all positions at once). A result
at or above the problem's clearance would be a valid layout with one more mug; below it, it says by how much
the search missed (a local optimum, not a bound). Mugs already on the tray are not modelled: problems with
any are refused.
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
REACH_MM = 15.0  # how far ``refine`` moves a brim from its start at most


@dataclass(frozen=True)
class Refined:
    """The brim centres after the search (tray mm, same order) and the clearance they keep: the least gap
    between two outlines and twice the least gap to a wall; ``iterations``: SLSQP's, 0 when it found
    nothing better than the start (which is then returned)."""

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

    def pieces(self, xy: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``xy`` (..., n, 2): every pair's gap between its parts (..., n (n - 1) / 2, 7: the discs, each
        disc to the other's handle, each handle's ends to the other handle), every mug's gap to the walls
        by part (..., n, 12: the disc and both handle ends to each wall), and the handles' distance (0 where
        they cross; the pieces' least is the pair's gap unless they do). Each piece is smooth almost
        everywhere, so SLSQP is given them one by one, not their least (which has kinks where two tie)."""
        cx, cy = xy[..., 0], xy[..., 1]
        yaw = np.arctan2(cy + self.origin[1], cx + self.origin[0]) + self.rel
        c, s = np.cos(yaw), np.sin(yaw)
        ax, ay = cx + self.h0 * c, cy + self.h0 * s
        bx, by = cx + self.h1 * c, cy + self.h1 * s
        i, j = self.i, self.j
        ri, rj, ti, tj = self.r[i], self.r[j], self.t[i], self.t[j]
        seg_i = (ax[..., i], ay[..., i], bx[..., i], by[..., i])
        seg_j = (ax[..., j], ay[..., j], bx[..., j], by[..., j])
        pairs = np.stack(
            [
                np.hypot(cx[..., i] - cx[..., j], cy[..., i] - cy[..., j]) - ri - rj,
                point_segment(cx[..., j], cy[..., j], *seg_i) - ti - rj,
                point_segment(cx[..., i], cy[..., i], *seg_j) - tj - ri,
                point_segment(seg_i[0], seg_i[1], *seg_j) - ti - tj,
                point_segment(seg_i[2], seg_i[3], *seg_j) - ti - tj,
                point_segment(seg_j[0], seg_j[1], *seg_i) - ti - tj,
                point_segment(seg_j[2], seg_j[3], *seg_i) - ti - tj,
            ],
            axis=-1,
        )
        tx, ty = self.size
        r, t = self.r, self.t
        walls = np.stack(
            [cx - r, tx - cx - r, cy - r, ty - cy - r]
            + [v - t for v in (ax, bx, ay, by)]
            + [tx - v - t for v in (ax, bx)]
            + [ty - v - t for v in (ay, by)],
            axis=-1,
        )
        handles = segment_segment(*seg_i, *seg_j)
        return np.asarray(pairs, np.float64), np.asarray(walls, np.float64), np.asarray(handles, np.float64)

    def gaps(self, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``xy`` (..., n, 2): the gaps of every pair (..., n (n - 1) / 2) and to the walls (..., n): the
        packer's distances (``shapes``), below 0 where outlines overlap."""
        pairs, walls, handles = self.pieces(xy)
        crossing = np.where(handles > 0, np.inf, -self.t[self.i] - self.t[self.j])
        return np.minimum(pairs.min(axis=-1), crossing), walls.min(axis=-1)


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
    if problem.placed or problem.strays:
        raise ValueError("refine: mugs already on the tray are not modelled")
    lay = _Layout(problem, mugs)
    n = len(mugs)
    start = np.asarray(brims, np.float64).reshape(n, 2)
    pairs, walls = lay.gaps(start)
    s0 = float(min(pairs.min(initial=math.inf), 2.0 * walls.min(initial=math.inf)))
    # Variables: the brims (2n) and s. Constraints: every piece of a pair's gap - s >= 0, every piece of a
    # gap to a wall - s / 2 >= 0.
    m = 7 * len(lay.i)

    def values(z: FloatArray) -> FloatArray:
        p, w, _ = lay.pieces(z[:, :-1].reshape(-1, n, 2))
        size = z[:, -1:]
        return np.concatenate([p.reshape(len(z), -1) - size, w.reshape(len(z), -1) - size / 2.0], axis=-1)

    def fun(z: FloatArray) -> FloatArray:
        return np.asarray(values(z[None, :])[0], np.float64)

    def jac(z: FloatArray) -> FloatArray:
        batch = np.repeat(z[None, :], 2 * n + 1, axis=0)
        batch[1:, : 2 * n] += _STEP_MM * np.eye(2 * n)
        v = values(batch)
        d = (v[1:] - v[0]) / _STEP_MM  # (2n, constraints)
        ds = np.concatenate([-np.ones(m), -0.5 * np.ones(12 * n)])
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
            # a local search: each brim within REACH_MM of its start, which keeps SLSQP's steps from
            # running off (with hundreds of constraints they did, to negative clearances)
            bounds=[(v - REACH_MM, v + REACH_MM) for v in start.ravel()] + [(0.0, None)],
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
    """A layout of ``count`` mugs (more than the problem's plan) that the planner packed at ``packed_at`` mm
    of clearance, then ``refined`` under the problem's clearance; ``mugs`` as for ``refine``."""

    count: int
    packed_at: int
    mugs: tuple[tuple[str, float], ...]
    refined: Refined


def one_more(problem: Problem, planned: int, *, options: PlanOptions, lowest_mm: int = 0) -> OneMore | None:
    """The first layout with more than ``planned`` mugs that the planner packs at a clearance below the
    problem's (1 mm less each time, down to ``lowest_mm``), refined under the problem's clearance; None
    when no clearance down to ``lowest_mm`` packs more (or there is nothing more to place)."""
    if problem.placed or problem.strays:
        raise ValueError("one_more: mugs already on the tray are not modelled")
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
