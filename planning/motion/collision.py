"""Collision checks with simple primitives: the gripper as small spheres, a held mug as a cylinder, and the
obstacles (mugs on the counter and the tray, the tray walls, the arm's base column, the counter top) as
vertical cylinders and boxes.

The thesis ran no collision checking (MoveIt! took over a minute per move) and instead carried mugs 3 cm
above the others (§4.3). Here that rule is the vertical clearance required between a held mug and any
obstacle it passes over, and every sampled pose of every motion is checked before anything is commanded.
The arm links behind the wrist are only checked against the counter top.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from description import thesis
from description.arm import GripperGeometry
from description.thesis import MugSpec
from drivers.interfaces import FloatArray
from planning.arm.model import ArmModel
from planning.motion.remembered import Lru

_FLOOR_MARGIN_M = 0.002
_LINK_FLOOR_MARGIN_M = 0.01
_CHECK_STEP_M = 0.01
_COUNTER = "the counter"
# Bounding boxes are widened by this before the exact sphere checks, so rounding cannot drop a contact.
_BOUND_SLACK_M = 1e-9
# A sweep's boxes (``Sweep``) are widened by this: far more than rounding, far less than any gap that matters.
_BOX_SLACK_M = 1e-6

# A collision found at one pose of a motion: the pose's index, why, and the obstacle's name.
_Finding = tuple[int, str, str]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class Cylinder:
    """A vertical cylinder obstacle (a mug body, a handle, the arm's base column)."""

    name: str
    x: float
    y: float
    radius: float
    z_lo: float
    z_hi: float


# The arm's base column (shoulder-turn servo, its bracket and the shoulder-lift servo) as an obstacle.
BASE_COLUMN: Final = Cylinder("the arm's base", 0.0, 0.0, 0.05, 0.0, 0.11)


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box obstacle (a tray wall)."""

    name: str
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Collision:
    """The first collision along a motion: why, and the obstacle met (its name, e.g. ``mug m9 handle``,
    ``the tray's near wall``, ``the counter``)."""

    why: str
    obstacle: str

    @property
    def mug_ids(self) -> frozenset[str]:
        """The id of the mug met, when the obstacle is a mug (obstacles of mugs are named ``mug <id>``)."""
        name = self.obstacle.removesuffix(" handle")
        return frozenset({name.removeprefix("mug ")}) if name.startswith("mug ") else frozenset()

    def __str__(self) -> str:
        return self.why


@dataclass(frozen=True, slots=True)
class HeldMug:
    """A mug in the gripper, in the grasp frame: its axis runs along the frame's x through
    (0, lateral, -behind) (the finger tips reach ``behind`` past it), the mug filling ``x_lo`` to ``x_hi``
    along it."""

    name: str
    radius: float
    lateral: float
    x_lo: float
    x_hi: float
    behind: float = 0.0


def mug_obstacles(
    name: str, x: float, y: float, spec: MugSpec, *, handle_yaw_rad: float, floor_z: float = 0.0
) -> list[Cylinder]:
    """A standing mug as its body cylinder and a thin cylinder where its handle is."""
    r = spec.diameter_mm / 2000.0
    h = spec.height_mm / 1000.0
    handle_r = max(0.005, (spec.width_mm / 1000.0 - 2 * r) / 2)
    hx = x + (r + handle_r) * math.cos(handle_yaw_rad)
    hy = y + (r + handle_r) * math.sin(handle_yaw_rad)
    return [
        Cylinder(name, x, y, r, floor_z, floor_z + h),
        Cylinder(f"{name} handle", hx, hy, handle_r, floor_z + 0.15 * h, floor_z + 0.85 * h),
    ]


def gripper_spheres(gripper: GripperGeometry, *, aperture_m: float) -> tuple[FloatArray, FloatArray]:
    """Sphere centres (n, 3) in the grasp frame and radii (n,) covering thumb, finger, palm, gripper servo
    and wrist, with the finger at ``aperture_m``."""
    l_g, w_g = gripper.finger_length_m, gripper.thumb_width_m
    centres: list[tuple[float, float, float]] = []
    radii: list[float] = []

    def add(points: Iterable[tuple[float, float, float]], r: float) -> None:
        for p in points:
            centres.append(p)
            radii.append(r)

    # Thumb and finger are plates 3 cm tall: rows of spheres through the plate's middle, as thick as the
    # plate, so they touch its inner face (where the mug is) and reach its outer face.
    plate = gripper.plate_thickness_m / 2
    along = np.arange(-l_g, 1e-9, 0.008)
    across = (-0.012, 0.0, 0.012)
    add(((x, -(w_g + plate), float(z)) for x in across for z in along), plate)
    angle = gripper.angle_for_aperture(aperture_m)
    hinge_y = gripper.hinge_offset_m
    for f in np.linspace(0.0, 1.0, len(along)):
        y = hinge_y - f * l_g * math.sin(angle) + plate
        z = -l_g + f * l_g * math.cos(angle)
        add(((x, y, z) for x in across), plate)
    t = gripper.plate_thickness_m
    palm = np.linspace(-(w_g + t) + 0.008, hinge_y + t - 0.008, 6)
    add(((x, float(y), -l_g) for x in (-0.012, 0.012) for y in palm), 0.008)
    add([(0.0, 0.0, -l_g - 0.02)], 0.02)  # gripper servo behind the palm
    add([(0.0, 0.0, -l_g - 0.07)], 0.022)  # wrist-turn servo
    return np.array(centres), np.array(radii)


@functools.lru_cache(maxsize=64)
def _gripper_spheres(gripper: GripperGeometry, aperture_m: float) -> tuple[FloatArray, FloatArray]:
    """``gripper_spheres``, computed once per gripper and aperture (a plan uses a handful of apertures);
    read-only, as they are shared."""
    centres, radii = gripper_spheres(gripper, aperture_m=aperture_m)
    centres.flags.writeable = False
    radii.flags.writeable = False
    return centres, radii


@dataclass(frozen=True, slots=True)
class Sweep:
    """The gripper along the sampled poses of a motion, which no obstacle changes: the grasp point's
    positions (N, 3) and rotations (N, 3, 3), the joints' heights (N, n-1), a height at or below the lowest
    point of its spheres (``low_bound``, (N,)), a box around its spheres (``lo``, ``hi``, (N, 3)) and, when
    kept, the spheres' centres (N, S, 3). Shared when remembered: never changed.

    The box is the world box of the spheres' box in the grasp frame (a few numbers per pose instead of a
    min and max over every sphere): a little larger than the spheres' own, so it only decides which poses
    are worth checking sphere by sphere, and the checks find the same first contact."""

    positions: FloatArray
    rotations: FloatArray
    joint_z: FloatArray
    low_bound: FloatArray
    lo: FloatArray
    hi: FloatArray
    centres: FloatArray | None

    def centres_at(self, spheres: FloatArray) -> Callable[[IntArray], FloatArray]:
        """The spheres' centres at some of the poses (worked out as ``CollisionWorld._sweep`` does: the
        same numbers)."""
        if self.centres is not None:
            kept = self.centres
            return lambda poses: kept[poses]
        return lambda poses: (
            self.positions[poses][:, None, :] + np.einsum("nij,sj->nsi", self.rotations[poses], spheres)
        )


# A sweep remembered by its sampled joint angles (bytes, shape) and the gripper's opening (hex).
SweepKey = tuple[bytes, tuple[int, ...], str]


class CollisionWorld:
    """The obstacles of one planning problem; checks sampled arm poses against them."""

    def __init__(
        self,
        arm: ArmModel,
        cylinders: Sequence[Cylinder],
        boxes: Sequence[Box],
        *,
        floor_z: float = 0.0,
        clearance_m: float = thesis.TRANSIT_CLEARANCE_M,
        sweeps: Lru[SweepKey, Sweep] | None = None,
    ) -> None:
        self.arm = arm
        # The gripper's sweeps along motions checked before (they do not depend on the obstacles).
        self.sweeps = sweeps
        self.cylinders = tuple(cylinders)
        self.boxes = tuple(boxes)
        self.floor_z = floor_z
        self.clearance_m = clearance_m
        self._cyl = np.array([[c.x, c.y, c.radius, c.z_lo, c.z_hi] for c in self.cylinders]).reshape(-1, 5)
        self._box_lo = np.array([b.lo for b in self.boxes]).reshape(-1, 3)
        self._box_hi = np.array([b.hi for b in self.boxes]).reshape(-1, 3)
        self._actives: dict[frozenset[str], BoolArray] = {}

    def first_collision(
        self,
        q_samples: FloatArray,
        *,
        aperture_m: float,
        held: HeldMug | None = None,
        ignore: frozenset[str] = frozenset(),
    ) -> Collision | None:
        """The first colliding pose's collision (None when every pose is clear). Poses are checked at the
        given samples and between them wherever the grasp point moved more than 1 cm."""
        spheres, radii = _gripper_spheres(self.arm.gripper, float(aperture_m))
        active = self._active(ignore)
        samples = np.ascontiguousarray(q_samples, dtype=np.float64)
        if self.sweeps is None:
            sweep = self._sweep(samples, spheres, radii)
        else:
            key = (samples.tobytes(), samples.shape, float(aperture_m).hex())
            sweep = self.sweeps.get(key, lambda: self._sweep(samples, spheres, radii, keep_centres=False))
        positions, rotations, joint_z = sweep.positions, sweep.rotations, sweep.joint_z
        findings: list[_Finding] = []
        low_joint = np.min(joint_z, axis=1) if joint_z.shape[1] else np.full(len(positions), np.inf)
        bad = np.flatnonzero(low_joint < self.floor_z + _LINK_FLOOR_MARGIN_M)
        if len(bad):
            i = int(bad[0])
            j = int(np.argmin(joint_z[i]))
            joint = self.arm.joint_names[j + 1]
            why = f"the {joint} joint would go below the counter (z={joint_z[i, j]:.3f} m)"
            findings.append((i, why, _COUNTER))
        centres_at = sweep.centres_at(spheres)
        near_floor = np.flatnonzero(sweep.low_bound < self.floor_z + _FLOOR_MARGIN_M)
        if len(near_floor):
            low = np.min(centres_at(near_floor)[:, :, 2] - radii[None, :], axis=1)
            bad = np.flatnonzero(low < self.floor_z + _FLOOR_MARGIN_M)
            if len(bad):
                i = int(near_floor[bad[0]])
                why = f"the gripper would touch the counter (z={low[bad[0]]:.3f} m)"
                findings.append((i, why, _COUNTER))
        hit_pose, name = self._near_vs_obstacles(sweep.lo, sweep.hi, centres_at, radii, active)
        if name:
            findings.append((hit_pose, f"the gripper would hit {name}", name))
        if held is not None:
            findings += self._held_collisions(positions, rotations, held, active)
        if not findings:
            return None
        pose, why, obstacle = min(findings, key=lambda f: f[0])
        return Collision(f"{why} (pose {pose} of {len(positions)})", obstacle)

    def _active(self, ignore: frozenset[str]) -> BoolArray:
        """Which cylinders count (not a mug of ``ignore``, nor its handle); worked out once per set ignored,
        as a world is checked against many motions with the same few (read-only, as it is shared)."""
        active = self._actives.get(ignore)
        if active is None:
            names = (c.name for c in self.cylinders)
            counted = [n not in ignore and n.removesuffix(" handle") not in ignore for n in names]
            active = np.array(counted, dtype=bool)
            active.flags.writeable = False
            self._actives[ignore] = active
        return active

    def _overlapping(self, low: FloatArray, high: FloatArray) -> tuple[BoolArray, IntArray]:
        """Which cylinders (a mask) and which boxes (their indices) the box ``low``, ``high`` (3,) around
        all of a sweep's boxes overlaps, by the tests ``_near_vs_obstacles`` makes pose by pose: an
        obstacle outside it is near no pose, so the pose by pose tests need not look at it."""
        cyl = self._cyl
        boxes = np.flatnonzero(np.logical_and.reduce((low < self._box_hi) & (high > self._box_lo), axis=1))
        overlapping: BoolArray = (
            (low[0] < cyl[:, 0] + cyl[:, 2])
            & (high[0] > cyl[:, 0] - cyl[:, 2])
            & (low[1] < cyl[:, 1] + cyl[:, 2])
            & (high[1] > cyl[:, 1] - cyl[:, 2])
            & (low[2] < cyl[:, 4])
            & (high[2] > cyl[:, 3])
        )
        return overlapping, boxes

    def mugs_around(self, q: FloatArray, *, aperture_m: float) -> frozenset[str]:
        """Ids of the mugs (named ``mug <id>``) the gripper overlaps at joint angles ``q``: after a failed or
        abandoned grasp the open gripper still straddles the mug it let go of."""
        if not len(self._cyl):
            return frozenset()
        spheres, radii = _gripper_spheres(self.arm.gripper, float(aperture_m))
        positions, rotations, _ = self._poses(np.asarray(q, dtype=np.float64)[None, :])
        centres = positions[0][None, :] + spheres @ rotations[0].T
        cyl = self._cyl
        dxy = np.hypot(centres[:, None, 0] - cyl[None, :, 0], centres[:, None, 1] - cyl[None, :, 1])
        r = radii[:, None]
        overlap = (
            (dxy < cyl[None, :, 2] + r)
            & (centres[:, None, 2] + r > cyl[None, :, 3])
            & (centres[:, None, 2] - r < cyl[None, :, 4])
        )
        names = (
            self.cylinders[int(i)].name.removesuffix(" handle") for i in np.flatnonzero(overlap.any(axis=0))
        )
        return frozenset(n.removeprefix("mug ") for n in names if n.startswith("mug "))

    def _sweep(
        self, samples: FloatArray, spheres: FloatArray, radii: FloatArray, *, keep_centres: bool = True
    ) -> Sweep:
        """The gripper's spheres along ``samples`` (see ``Sweep``); their centres kept when ``keep_centres``
        (a sweep remembered keeps only the poses and bounds, its centres are worked out again as needed)."""
        positions, rotations, joint_z = self._poses(samples)
        centre, half = _frame_box(spheres, radii)
        middle = positions + rotations @ centre
        extent = np.abs(rotations) @ half + _BOX_SLACK_M
        world = positions[:, None, :] + np.einsum("nij,sj->nsi", rotations, spheres) if keep_centres else None
        lo, hi = middle - extent, middle + extent
        return Sweep(positions, rotations, joint_z, lo[:, 2], lo, hi, world)

    def _poses(self, q_samples: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Grasp-point positions (N, 3), rotations (N, 3, 3) and the heights of the joints after the shoulder
        turn (N, n-1), densified so the grasp point moves at most 1 cm between poses."""
        samples = np.asarray(q_samples, dtype=np.float64).reshape(-1, self.arm.dof)
        positions, rotations, origins = self.arm.fk_many(samples)
        if len(samples) > 1:
            gaps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
            steps = np.ceil(gaps / _CHECK_STEP_M).astype(np.int64)
            if np.any(steps > 1):
                # Each sample, preceded by the poses between it and the previous one: sample k follows
                # prev + (q - prev) * j / n for j = 1 .. n-1 (n = steps[k - 1]), all at once.
                n = np.maximum(steps, 1)
                k = np.repeat(np.arange(1, len(samples)), n)
                n_row = np.repeat(n, n)
                j = np.arange(1, len(k) + 1) - np.repeat(np.cumsum(n) - n, n)
                prev, q = samples[k - 1], samples[k]
                between = prev + (q - prev) * (j / n_row)[:, None]
                rows = np.where((j < n_row)[:, None], between, q)
                positions, rotations, origins = self.arm.fk_many(np.concatenate([samples[:1], rows]))
        return positions, rotations, origins[:, 1:, 2]

    def _spheres_vs_obstacles(
        self, centres: FloatArray, radii: FloatArray, active: BoolArray
    ) -> tuple[int, str]:
        """First pose (axis 0 of ``centres`` (N, S, 3)) where a sphere meets an obstacle, and its name."""
        lo, hi = _bounds(centres, radii)
        return self._near_vs_obstacles(lo, hi, lambda poses: centres[poses], radii, active)

    def _near_vs_obstacles(
        self,
        lo: FloatArray,
        hi: FloatArray,
        centres_at: Callable[[IntArray], FloatArray],
        radii: FloatArray,
        active: BoolArray,
    ) -> tuple[int, str]:
        """First pose where a sphere meets an obstacle, and its name: ``lo``, ``hi`` (N, 3) bound each pose's
        spheres, ``centres_at(poses)`` gives the spheres' centres (len(poses), S, 3) at those poses.

        Only the (pose, obstacle) pairs whose bounding boxes overlap are checked sphere by sphere: a pose's
        spheres are near a few obstacles at most, and the obstacles outside the box around all of them are
        left out first."""
        first = len(lo)
        name = ""
        if not len(lo):
            return first, name
        near_all, boxes = self._overlapping(np.minimum.reduce(lo, axis=0), np.maximum.reduce(hi, axis=0))
        active = active & near_all
        cyl = self._cyl[active]
        if len(cyl):
            near = (
                (lo[:, None, 0] < cyl[None, :, 0] + cyl[None, :, 2])
                & (hi[:, None, 0] > cyl[None, :, 0] - cyl[None, :, 2])
                & (lo[:, None, 1] < cyl[None, :, 1] + cyl[None, :, 2])
                & (hi[:, None, 1] > cyl[None, :, 1] - cyl[None, :, 2])
                & (lo[:, None, 2] < cyl[None, :, 4])
                & (hi[:, None, 2] > cyl[None, :, 3])
            )
            pose, which = np.nonzero(near)
            if len(pose):
                c = _centres_once(centres_at, pose)  # (P, S, 3) against cyl[which] (P, 5)
                o = cyl[which][:, None, :]
                rr = radii[None, :]
                dxy = np.hypot(c[:, :, 0] - o[:, :, 0], c[:, :, 1] - o[:, :, 1])
                overlap = (dxy < o[:, :, 2] + rr) & (
                    (c[:, :, 2] + rr > o[:, :, 3]) & (c[:, :, 2] - rr < o[:, :, 4])
                )
                hit = np.flatnonzero(np.any(overlap, axis=1))
                if len(hit):
                    # Pairs are in (pose, obstacle) order: the first hit is the first pose's first obstacle.
                    first = int(pose[hit[0]])
                    name = self.cylinders[int(np.flatnonzero(active)[which[hit[0]]])].name
        if len(boxes):
            box_lo, box_hi = self._box_lo[boxes], self._box_hi[boxes]
            near = np.all(
                (lo[:, None, :] < box_hi[None, :, :]) & (hi[:, None, :] > box_lo[None, :, :]), axis=2
            )
            pose, which = np.nonzero(near[:first])
            which = boxes[which]
            if len(pose):
                c = _centres_once(centres_at, pose)
                nearest = np.clip(c, self._box_lo[which][:, None, :], self._box_hi[which][:, None, :])
                dist = np.linalg.norm(c - nearest, axis=2)
                hit = np.flatnonzero(np.any(dist < radii[None, :], axis=1))
                if len(hit) and int(pose[hit[0]]) < first:
                    first = int(pose[hit[0]])
                    name = self.boxes[int(which[hit[0]])].name
        return first, name

    def _held_collisions(
        self, positions: FloatArray, rotations: FloatArray, held: HeldMug, active: BoolArray
    ) -> list[_Finding]:
        findings: list[_Finding] = []
        axis = rotations[:, :, 0]
        centre = positions + rotations[:, :, 1] * held.lateral - rotations[:, :, 2] * held.behind
        base = centre + axis * held.x_lo
        top = centre + axis * held.x_hi
        vertical = np.abs(axis[:, 2]) > 0.999
        upright = np.flatnonzero(vertical)
        if len(upright):
            z_lo = np.minimum(base[upright, 2], top[upright, 2])
            z_hi = np.maximum(base[upright, 2], top[upright, 2])
            on_floor = z_lo < self.floor_z - 1e-6
            cyl_hits, box_hits = self._held_cylinders_vs_obstacles(
                base[upright, :2], held.radius, z_lo, z_hi, active
            )
            bad = np.flatnonzero(on_floor | cyl_hits.any(axis=1) | box_hits.any(axis=1))
            if len(bad):
                k = int(bad[0])
                i = int(upright[k])
                if on_floor[k]:
                    why = f"the held {held.name} would touch the counter (z={float(z_lo[k]):.3f} m)"
                    findings.append((i, why, _COUNTER))
                else:
                    hits = np.flatnonzero(cyl_hits[k])
                    hit = (
                        self.cylinders[int(hits[0])].name
                        if len(hits)
                        else self.boxes[int(np.flatnonzero(box_hits[k])[0])].name
                    )
                    findings.append((i, f"the held {held.name} would hit {hit}", hit))
        tilted = np.flatnonzero(~vertical)
        if len(tilted):
            n = max(2, math.ceil((held.x_hi - held.x_lo) / held.radius * 2))
            f = np.linspace(0.0, 1.0, n)
            chain = base[tilted, None, :] + f[None, :, None] * (top[tilted] - base[tilted])[:, None, :]
            mug_radii = np.full(n, held.radius)
            low = np.min(chain[:, :, 2], axis=1) - held.radius
            bad = np.flatnonzero(low < self.floor_z)
            if len(bad):
                why = f"the held {held.name} would touch the counter while turning"
                findings.append((int(tilted[bad[0]]), why, _COUNTER))
            pose, name = self._spheres_vs_obstacles(chain, mug_radii, active)
            if name:
                why = f"the held {held.name} would hit {name} while turning"
                findings.append((int(tilted[pose]), why, name))
        return findings

    def _held_cylinders_vs_obstacles(
        self, xy: FloatArray, radius: float, z_lo: FloatArray, z_hi: FloatArray, active: BoolArray
    ) -> tuple[BoolArray, BoolArray]:
        """A held, upright mug must keep ``clearance_m`` above anything it overlaps in plan view. For mugs
        at ``xy`` (V, 2) spanning ``z_lo``-``z_hi`` (V,): which cylinders (V, C) and boxes (V, B) each
        comes too close to. Only the cylinders within reach of the box around all the mugs' axes (widened
        by far more than rounding) are looked at pose by pose: no other can be that close to any."""
        gap = self.clearance_m
        cyl = self._cyl
        reach = radius + cyl[:, 2] + _BOX_SLACK_M
        low, high = np.minimum.reduce(xy, axis=0), np.maximum.reduce(xy, axis=0)
        near = np.flatnonzero(
            active
            & (low[0] < cyl[:, 0] + reach)
            & (high[0] > cyl[:, 0] - reach)
            & (low[1] < cyl[:, 1] + reach)
            & (high[1] > cyl[:, 1] - reach)
        )
        cyl_hits = np.zeros((len(xy), len(cyl)), dtype=bool)
        if len(near):
            c = cyl[near]
            dxy = np.hypot(xy[:, None, 0] - c[None, :, 0], xy[:, None, 1] - c[None, :, 1])
            cyl_hits[:, near] = (
                (dxy < radius + c[None, :, 2])
                & (z_lo[:, None] < c[None, :, 4] + gap)
                & (z_hi[:, None] > c[None, :, 3] - gap)
            )
        lo, hi = self._box_lo, self._box_hi
        dx = np.maximum(np.maximum(lo[None, :, 0] - xy[:, None, 0], 0.0), xy[:, None, 0] - hi[None, :, 0])
        dy = np.maximum(np.maximum(lo[None, :, 1] - xy[:, None, 1], 0.0), xy[:, None, 1] - hi[None, :, 1])
        box_hits = (
            (np.hypot(dx, dy) < radius)
            & (z_lo[:, None] < hi[None, :, 2] + gap)
            & (z_hi[:, None] > lo[None, :, 2] - gap)
        )
        return cyl_hits, box_hits


def _centres_once(centres_at: Callable[[IntArray], FloatArray], poses: IntArray) -> FloatArray:
    """``centres_at(poses)`` for ascending ``poses`` with repeats (a pose near a mug's body and its handle),
    each pose's spheres worked out once."""
    new = np.diff(poses, prepend=-1) != 0  # the first of each run of one pose
    if new.all():
        return centres_at(poses)
    once: FloatArray = centres_at(poses[new])
    return np.asarray(once[np.cumsum(new) - 1], dtype=np.float64)


def _frame_box(spheres: FloatArray, radii: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centre and half-size (3,) of the box around spheres (``spheres`` (S, 3) centres, ``radii`` (S,))."""
    lo = np.min(spheres - radii[:, None], axis=0)
    hi = np.max(spheres + radii[:, None], axis=0)
    return (lo + hi) / 2, (hi - lo) / 2


def _bounds(centres: FloatArray, radii: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Lower and upper corners (N, 3) of each pose's spheres' bounding box (axis 0 of ``centres``)."""
    r = radii[None, :, None]
    return np.min(centres - r, axis=1) - _BOUND_SLACK_M, np.max(centres + r, axis=1) + _BOUND_SLACK_M


def tray_walls(bounds: tuple[float, float, float, float], *, height: float, thickness: float) -> list[Box]:
    """The four walls around the inner tray rectangle (x_min, y_min, x_max, y_max)."""
    x0, y0, x1, y1 = bounds
    t = thickness
    return [
        Box("the tray's near wall", (x0 - t, y0 - t, 0.0), (x0, y1 + t, height)),
        Box("the tray's far wall", (x1, y0 - t, 0.0), (x1 + t, y1 + t, height)),
        Box("the tray's right wall", (x0, y0 - t, 0.0), (x1, y0, height)),
        Box("the tray's left wall", (x0, y1, 0.0), (x1, y1 + t, height)),
    ]
