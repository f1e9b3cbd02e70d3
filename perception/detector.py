"""Mug detection on depth frames: table plane, top-view height map, brim fit, type, pose, handle, confidence.

The pipeline works on geometry only, so it does not mistake one mug type for the other or see mugs on an empty
counter, as the thesis's appearance model did (§5.1):

1. Back-project the valid pixels through the intrinsics and the extrinsics into the world frame.
2. Fit the table plane (RANSAC, then least squares) to the points near z = 0 and re-level the cloud on it, so
   a slightly wrong extrinsic does not tilt the heights.
3. Rasterise everything above the plane into a top-view height map (the highest point per cell). The map is
   independent of how densely the camera samples a surface, which is what makes the circle fits unbiased.
4. For each catalogue type, tallest first, take the cells at that type's brim height (the brim band) and
   vote for circle centres with the boundaries of those cells (a circular Hough transform at the brim
   radius). Votes come from whatever part of the brim is visible, so a half-hidden mug is still found.
5. Refine every peak with a geometric circle fit, classify it as upright (an open ring at the brim, the
   inside much lower) or upside down (a closed disc on top), check height, diameter, roundness and that the
   surface ends at the brim (a ball's does not, nor a box's), and find the handle as the cells beside the
   wall at handle height.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final, TypeVar

import cv2
import numpy as np
import numpy.typing as npt
import structlog

from description.thesis import MugSpec
from drivers.interfaces import CameraIntrinsics, FloatArray, RGBDFrame
from perception.errors import FrameError
from perception.interfaces import Detection

log = structlog.get_logger(__name__)

BoolArray = npt.NDArray[np.bool_]
_G = TypeVar("_G", bound=np.generic)
F32Array = npt.NDArray[np.float32]

# How far the brim's top face sits inside the outer radius (half a typical ceramic wall): the brim ring the
# detector fits lies there. Not a thesis figure.
RIM_INSET_M: Final = 0.002


@dataclass(frozen=True, slots=True)
class DetectorParams:
    """Tuning of ``DepthMugDetector``; the defaults suit a Kinect-class camera 1–2 m from the counter."""

    cell_m: float = 0.002  # top-view raster resolution
    min_height_m: float = 0.012  # points lower than this above the plane are the table
    max_height_m: float = 0.40
    densify_step_m: float = 0.004  # vertically adjacent pixels this close in height are one level surface
    plane_prior_m: float = 0.04  # the table is sought among points this close to the world's z = 0
    plane_inlier_m: float = 0.006
    min_table_extent_m: float = 0.15  # the table must be seen at least this far across in x and in y
    ransac_iterations: int = 40
    ransac_sample: int = 4000
    band_below_m: float = 0.014  # brim band: cells this far below a type's height ...
    band_above_m: float = 0.016  # ... up to this far above it (a tray lifts a mug a few millimetres)
    min_votes: float = 0.70  # Hough peak: this fraction of a full circle of brim edge must agree
    min_support: float = 0.55  # fraction of the fitted brim circle that must be seen
    max_residual_m: float = 0.0024  # RMS distance of the brim cells from the fitted circle: it must be round
    max_spill_m: float = 0.004  # how far the surface at brim height may reach past the brim (box corners do)
    diameter_tolerance_m: float = 0.010
    height_tolerance_m: float = 0.014
    max_inside_fraction: float = 0.12  # an open mug's inside is empty below the brim
    max_outside_fraction: float = 0.25  # the wall drops steeply: little as high as the brim just outside it
    handle_min_cells: int = 6
    seed: int = 0


@dataclass(frozen=True, slots=True)
class MugFit:
    """One brim fit in the re-levelled table frame, with the evidence it is (or is not) a mug of ``spec``."""

    spec: MugSpec
    x_m: float
    y_m: float
    radius_m: float
    height_m: float
    upside_down: bool
    support: float  # fraction of the brim circle seen
    residual_m: float  # RMS distance of the brim cells from the circle
    free_radius: bool  # the radius was fitted (enough of the brim seen), not taken from the catalogue
    inside_fraction: float
    outside_fraction: float
    spill_m: float  # how far the brim-height surface through the circle reaches beyond the outer radius

    def rejection(self, p: DetectorParams) -> str:
        """Why this is not a mug of its type ("" when it is)."""
        h = self.spec.height_mm / 1000.0
        target = self.spec.diameter_mm / 2000.0 - (0.0 if self.upside_down else RIM_INSET_M)
        if self.support < p.min_support:
            return "support"
        if self.residual_m > p.max_residual_m or self.spill_m > p.max_spill_m:
            return "not round"
        if not h - p.height_tolerance_m <= self.height_m <= h + p.band_above_m:
            return "height"
        if self.free_radius and abs(self.radius_m - target) > p.diameter_tolerance_m / 2:
            return "diameter"
        if not self.upside_down and self.inside_fraction > p.max_inside_fraction:
            return "inside"
        if self.outside_fraction > p.max_outside_fraction:
            return "outside"
        return ""


class DepthMugDetector:
    """Finds the catalogue's mugs in a depth frame and reports them in the world frame.

    ``region_m`` (x_min, y_min, x_max, y_max) limits the search to part of the table in world coordinates;
    by default the whole table plane in view is searched. Mugs whose centre lies in one of the ``exclude_m``
    rectangles (the tray, say, whose mugs are done) are not reported; they are still found, so they cannot be
    mistaken for something else.
    """

    def __init__(
        self,
        catalogue: Mapping[str, MugSpec],
        *,
        params: DetectorParams | None = None,
        region_m: tuple[float, float, float, float] | None = None,
        exclude_m: Sequence[tuple[float, float, float, float]] = (),
    ) -> None:
        if not catalogue:
            raise ValueError("the mug catalogue is empty; configure at least one [mug_types.<name>]")
        self._catalogue = dict(catalogue)
        self._params = params or DetectorParams()
        self._region = region_m
        self._exclude = tuple(exclude_m)
        self._grids: dict[CameraIntrinsics, tuple[F32Array, F32Array]] = {}
        self._kernels: dict[int, F32Array] = {}

    @property
    def catalogue(self) -> Mapping[str, MugSpec]:
        return self._catalogue

    def detect(self, frame: RGBDFrame) -> list[Detection]:
        """The mugs in ``frame``, in the world frame; raises ``FrameError`` when no table is in view.

        Positions are measured in the re-levelled table frame, which is the world frame as the cell defines
        it (z = 0 on the counter top, z up) with the extrinsic's tilt error removed.
        """
        fits, camera_xy, raster = self.fit(frame)
        verdicts = [(f, f.rejection(self._params)) for f in fits]
        accepted = [f for f, reason in verdicts if not reason]
        rejected = Counter(reason for _, reason in verdicts if reason)
        log.debug("brims_fitted", accepted=len(accepted), rejected=dict(rejected))
        detections = []
        for fit in accepted:
            if any(x0 <= fit.x_m <= x1 and y0 <= fit.y_m <= y1 for x0, y0, x1, y1 in self._exclude):
                continue
            others = [f for f in accepted if f is not fit]
            yaw, seen = _handle_yaw(raster, fit, others, camera_xy, self._params)
            detections.append(
                Detection(
                    type=fit.spec.name,
                    x_m=fit.x_m,
                    y_m=fit.y_m,
                    upside_down=fit.upside_down,
                    handle_yaw_rad=yaw,
                    confidence=_confidence(fit, seen, self._params),
                    handle_seen=seen,
                )
            )
        detections.sort(key=lambda d: (d.x_m, d.y_m))
        return detections

    def fit(self, frame: RGBDFrame) -> tuple[list[MugFit], FloatArray, _HeightMap]:
        """Every brim fit, accepted or not (for diagnosis), the camera's xy in the levelled frame and the
        height map."""
        p = self._params
        K = frame.intrinsics
        if frame.depth_m.shape != (K.height, K.width):
            raise FrameError(
                f"depth image is {frame.depth_m.shape[1]}x{frame.depth_m.shape[0]} pixels but the intrinsics "
                f"say {K.width}x{K.height}"
            )
        world_from_camera = np.asarray(frame.world_from_camera, dtype=np.float64)
        if world_from_camera.shape != (4, 4) or not np.all(np.isfinite(world_from_camera)):
            raise FrameError("world_from_camera must be a finite 4x4 matrix")
        box = (slice(0, K.height), slice(0, K.width))
        if self._region is not None:
            box = _pixels_seeing(self._region, p.max_height_m, K, world_from_camera)
        grid = self._pixel_grid(frame, box)
        table_from_world, table_xy = _level_on_table(grid, world_from_camera, p)
        table_from_camera = table_from_world @ world_from_camera
        region = self._region or _region_around(table_xy)
        raster = _HeightMap.build(grid, table_from_camera, region, p)
        camera_xy = table_from_camera[:2, 3]
        return self._fit_mugs(raster, camera_xy), camera_xy, raster

    def _pixel_grid(self, frame: RGBDFrame, box: tuple[slice, slice]) -> _PixelGrid:
        """The pixels in ``box`` (rows, columns) and their rays; NaN or infinite depth is no reading."""
        K = frame.intrinsics
        z = np.asarray(frame.depth_m, dtype=np.float32)[box]
        finite = np.isfinite(z)
        if not finite.all():
            z = np.where(finite, z, np.float32(0.0))
        valid = z > 0
        count = int(valid.sum())
        if count < 100:
            raise FrameError(f"the depth image has only {count} valid pixels; is the camera covered?")
        if K not in self._grids:
            u = (np.arange(K.width, dtype=np.float32) - np.float32(K.cx)) / np.float32(K.fx)
            v = (np.arange(K.height, dtype=np.float32) - np.float32(K.cy)) / np.float32(K.fy)
            self._grids[K] = (
                np.ascontiguousarray(np.broadcast_to(u[None, :], (K.height, K.width))),
                np.ascontiguousarray(np.broadcast_to(v[:, None], (K.height, K.width))),
            )
        rx, ry = self._grids[K]
        return _PixelGrid(rx[box], ry[box], z, valid)

    def _fit_mugs(self, raster: _HeightMap, camera_xy: FloatArray) -> list[MugFit]:
        p = self._params
        suppressed = np.zeros(raster.top.shape, dtype=bool)
        fits: list[MugFit] = []
        for spec in sorted(self._catalogue.values(), key=lambda s: -s.height_mm):
            h = spec.height_mm / 1000.0
            band = (raster.top >= h - p.band_below_m) & (raster.top <= h + p.band_above_m) & ~suppressed
            if not band.any():
                continue
            band_u8 = cv2.morphologyEx(band.astype(np.uint8), cv2.MORPH_CLOSE, _CROSS)
            filled_u8 = cv2.morphologyEx(band_u8, cv2.MORPH_CLOSE, _DISC5)
            filled = filled_u8.astype(bool)
            disc_edges = filled & ~cv2.erode(filled_u8, _CROSS).astype(bool)
            band = band_u8.astype(bool)
            rim_r = spec.diameter_mm / 2000.0 - RIM_INSET_M
            for row, col, _ in self._hough_peaks(band, rim_r / p.cell_m):
                fit = _refine(raster, band, filled, disc_edges, spec, (row, col), camera_xy)
                if fit is None:
                    continue
                fits.append(fit)
                if not fit.rejection(p):
                    # Its body is taken; a neighbour's brim may come within a few millimetres of it.
                    _paint_disc(suppressed, raster, (fit.x_m, fit.y_m), spec.diameter_mm / 2000.0 + 0.008)
        return fits

    def _hough_peaks(self, band: BoolArray, radius_cells: float) -> list[tuple[float, float, float]]:
        """Candidate brim centres (row, column in raster cells, votes), strongest first.

        The votes are cast on a raster ``_HOUGH_FACTOR`` times as coarse as the height map: the peak only has
        to fall within the refinement's reach (a centimetre), and the coarse vote is far less work.
        """
        f = _HOUGH_FACTOR
        eroded = cv2.erode(band.astype(np.uint8), _CROSS)
        boundary = (band & ~eroded.astype(bool)).astype(np.float32)
        h, w = boundary.shape
        boundary = boundary[: h - h % f, : w - w % f]
        coarse = cv2.resize(boundary, None, fx=1 / f, fy=1 / f, interpolation=cv2.INTER_AREA) * float(f * f)
        r = radius_cells / f
        key = round(r * 10)
        if key not in self._kernels:
            self._kernels[key] = _ring_kernel(r, f)
        votes = cv2.filter2D(coarse, cv2.CV_32F, self._kernels[key], borderType=cv2.BORDER_CONSTANT)
        local_max = cv2.dilate(votes, _SQUARE5)
        ys, xs = np.nonzero((votes >= local_max) & (votes >= self._params.min_votes))
        order = np.argsort(-votes[ys, xs])
        peaks: list[tuple[float, float, float]] = []
        min_sq = (1.6 * r) ** 2
        for i in order:
            if all((ys[i] - a) ** 2 + (xs[i] - b) ** 2 > min_sq for a, b, _ in peaks):
                peaks.append((float(ys[i]), float(xs[i]), float(votes[ys[i], xs[i]])))
        centre = (f - 1) / 2  # fine-cell index of a coarse cell's centre
        return [(f * a + centre, f * b + centre, v) for a, b, v in peaks]


_CROSS: Final = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
_DISC5: Final = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_SQUARE5: Final = np.ones((5, 5), np.uint8)
_HOUGH_FACTOR: Final = 3


def _ring_kernel(radius_cells: float, factor: int) -> F32Array:
    """A ring of width ±1 cell on a raster ``factor`` times coarser than the height map, normalised so a
    full circle of boundary cells at the radius scores 1 (a brim seen all round, inner and outer edge, 2).

    A coarse cell sums the boundary cells of ``factor``² fine ones, and a fine circle of radius R crosses
    ``factor`` times as many cells as the coarse ring of radius R / ``factor`` holds along its length."""
    n = math.ceil(radius_cells) + 2
    yy, xx = np.mgrid[-n : n + 1, -n : n + 1]
    ring: F32Array = (np.abs(np.hypot(yy, xx) - radius_cells) <= 1.0).astype(np.float32)
    return ring / np.float32(ring.sum() * factor / 2.0)


@dataclass(frozen=True, slots=True)
class _PixelGrid:
    """The depth image with each pixel's normalised ray (x/z, y/z): a pixel's point is (rx·z, ry·z, z)."""

    rx: F32Array
    ry: F32Array
    z: F32Array
    valid: BoolArray


def _pixels_seeing(
    region: tuple[float, float, float, float],
    height_m: float,
    K: CameraIntrinsics,
    world_from_camera: FloatArray,
) -> tuple[slice, slice]:
    """The image rows and columns that can see the search region (up to ``height_m`` above the table), with
    a margin for an extrinsic that is a little off; the whole image when the region reaches behind the camera.
    """
    x0, y0, x1, y1 = region
    corners = np.array([(x, y, z, 1.0) for x in (x0, x1) for y in (y0, y1) for z in (0.0, height_m)])
    cam = (np.linalg.inv(world_from_camera) @ corners.T)[:3]
    if np.any(cam[2] <= 0.05):
        return slice(0, K.height), slice(0, K.width)
    u = K.fx * cam[0] / cam[2] + K.cx
    v = K.fy * cam[1] / cam[2] + K.cy
    margin = 0.05 * max(K.width, K.height)
    c0, c1 = max(int(u.min() - margin), 0), min(int(u.max() + margin) + 1, K.width)
    r0, r1 = max(int(v.min() - margin), 0), min(int(v.max() + margin) + 1, K.height)
    if c1 - c0 < 2 or r1 - r0 < 2:
        return slice(0, K.height), slice(0, K.width)
    return slice(r0, r1), slice(c0, c1)


def _coordinate(T: FloatArray, axis: int, rx: F32Array, ry: F32Array, z: F32Array) -> F32Array:
    """One coordinate of camera points (rx·z, ry·z, z) in the frame ``T`` (4×4, from the camera) maps into."""
    a, b, c, d = (np.float32(v) for v in T[axis])
    out: F32Array = (a * rx + b * ry + c) * z + d
    return out


@dataclass(frozen=True, slots=True)
class _HeightMap:
    """Top-view raster: the highest point above the table per cell (0 where nothing stands)."""

    top: F32Array  # (rows along y, cols along x)
    x0: float
    y0: float
    cell: float

    @classmethod
    def build(
        cls,
        grid: _PixelGrid,
        table_from_camera: FloatArray,
        region: tuple[float, float, float, float],
        p: DetectorParams,
    ) -> _HeightMap:
        """Rasterise the points above the table. A camera looking down at a slant samples a level surface
        (a brim, a closed bottom) sparsely along the line of sight, so two points are interpolated between
        vertically adjacent pixels at the same height to close those gaps."""
        T = table_from_camera
        zt = _coordinate(T, 2, grid.rx, grid.ry, grid.z)
        above = grid.valid & (zt > p.min_height_m) & (zt < p.max_height_m)
        d = grid.z
        pair = (
            grid.valid[:-1]
            & grid.valid[1:]
            & (above[:-1] | above[1:])
            & (np.abs(zt[1:] - zt[:-1]) < p.densify_step_m)
        )
        r, c = np.nonzero(pair)
        rx_parts, ry_parts, z_parts = [grid.rx[above]], [grid.ry[above]], [d[above]]
        if r.size:
            d0, d1 = d[r, c], d[r + 1, c]
            ry0, ry1 = grid.ry[r, c], grid.ry[r + 1, c]
            rxc = grid.rx[r, c]
            for t in (np.float32(1 / 3), np.float32(2 / 3)):
                rx_parts.append(rxc)
                ry_parts.append(ry0 + t * (ry1 - ry0))
                z_parts.append(d0 + t * (d1 - d0))
        rx, ry, z = np.concatenate(rx_parts), np.concatenate(ry_parts), np.concatenate(z_parts)
        h = _coordinate(T, 2, rx, ry, z)
        keep = (h > p.min_height_m) & (h < p.max_height_m)
        rx, ry, z, h = rx[keep], ry[keep], z[keep], h[keep]
        x0, y0, x1, y1 = region
        nx = max(math.ceil((x1 - x0) / p.cell_m), 1)
        ny = max(math.ceil((y1 - y0) / p.cell_m), 1)
        ix = np.floor((_coordinate(T, 0, rx, ry, z) - x0) / p.cell_m).astype(np.int64)
        iy = np.floor((_coordinate(T, 1, rx, ry, z) - y0) / p.cell_m).astype(np.int64)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        top = np.zeros(ny * nx, dtype=np.float32)
        np.maximum.at(top, iy[inside] * nx + ix[inside], h[inside])
        return cls(top.reshape(ny, nx), x0, y0, p.cell_m)

    def centre_of(self, row: float, col: float) -> tuple[float, float]:
        """Table xy of a (fractional) cell index: cell (0, 0) spans [x0, x0 + cell) × [y0, y0 + cell)."""
        return self.x0 + (col + 0.5) * self.cell, self.y0 + (row + 0.5) * self.cell

    def window(self, xy: tuple[float, float], radius_m: float) -> _Window:
        """The cells around ``xy`` with their offsets from it (metres)."""
        c0 = max(int((xy[0] - radius_m - self.x0) / self.cell), 0)
        c1 = min(int((xy[0] + radius_m - self.x0) / self.cell) + 2, self.top.shape[1])
        r0 = max(int((xy[1] - radius_m - self.y0) / self.cell), 0)
        r1 = min(int((xy[1] + radius_m - self.y0) / self.cell) + 2, self.top.shape[0])
        dy = (self.y0 + (np.arange(r0, r1) + 0.5) * self.cell - xy[1])[:, None]
        dx = (self.x0 + (np.arange(c0, c1) + 0.5) * self.cell - xy[0])[None, :]
        return _Window.around(slice(r0, r1), slice(c0, c1), xy, dx, dy)


@dataclass(frozen=True, slots=True)
class _Window:
    """A block of raster cells and each cell's offset from ``centre`` (table frame, metres)."""

    rows: slice
    cols: slice
    centre: tuple[float, float]
    gx: FloatArray  # (h, w) offsets along x
    gy: FloatArray  # (h, w) offsets along y
    dist: FloatArray  # (h, w)

    @classmethod
    def around(
        cls, rows: slice, cols: slice, centre: tuple[float, float], dx: FloatArray, dy: FloatArray
    ) -> _Window:
        """From the column offsets ``dx`` (1, w) and row offsets ``dy`` (h, 1)."""
        # Plain arithmetic builds the dense grids far faster than numpy's broadcasting helpers.
        return cls(rows, cols, centre, dx + 0.0 * dy, dy + 0.0 * dx, np.sqrt(dx * dx + dy * dy))

    def shifted(self, ox: float, oy: float) -> _Window:
        """The same cells, measured from a centre moved by (ox, oy)."""
        centre = (self.centre[0] + ox, self.centre[1] + oy)
        return _Window.around(self.rows, self.cols, centre, self.gx[:1, :] - ox, self.gy[:, :1] - oy)

    def of(self, image: npt.NDArray[_G]) -> npt.NDArray[_G]:
        return image[self.rows, self.cols]


def _paint_disc(mask: BoolArray, raster: _HeightMap, xy: tuple[float, float], radius_m: float) -> None:
    w = raster.window(xy, radius_m)
    mask[w.rows, w.cols] |= w.dist <= radius_m


def _refine(
    raster: _HeightMap,
    band: BoolArray,
    filled: BoolArray,
    disc_edges: BoolArray,
    spec: MugSpec,
    peak: tuple[float, float],
    camera_xy: FloatArray,
) -> MugFit | None:
    """Fit the brim around a Hough peak and measure the evidence that it is a mug of this type.

    None when there is too little brim to fit at all; otherwise ``MugFit.rejection`` decides.

    Seen from above at a slant, an open brim shows its outer face on the side towards the camera and its
    inner face on the far side (the thin top of the brim is hardly sampled there), so the fitted circle sits
    half a wall towards the camera and half a wall too small. The centre is moved back by the difference
    between the catalogue's outer radius and the fitted one.
    """
    R = spec.diameter_mm / 2000.0
    rim_r = R - RIM_INSET_M
    h = spec.height_mm / 1000.0
    w = raster.window(raster.centre_of(*peak), R + 0.022)
    inner = w.dist < 0.6 * rim_r
    upside_down = bool(w.of(filled)[inner].mean() > 0.5) if inner.any() else False
    # An open mug shows a ring at its brim; an upside-down one a closed disc whose edge is the brim.
    edges, target_r = (w.of(disc_edges), R) if upside_down else (w.of(band), rim_r)
    radius, residual, free = target_r, 0.0, False
    for tolerance in (0.010, 0.005):
        use = edges & (np.abs(w.dist - target_r) < tolerance)
        if use.sum() < 8:
            return None
        dx, dy = w.gx[use], w.gy[use]
        coverage = _coverage(dx, dy)
        if coverage < 0.5:
            return None
        free = coverage >= 0.7
        (ox, oy), radius, residual = _fit_circle(dx, dy, target_r, free_radius=free)
        w = w.shifted(ox, oy)
    if not upside_down:
        away = np.array(w.centre) - camera_xy
        away /= max(float(np.linalg.norm(away)), 1e-9)
        inset = R - radius if free else RIM_INSET_M
        w = w.shifted(float(away[0]) * inset, float(away[1]) * inset)
    top = w.of(raster.top)
    seen = w.of(filled) if upside_down else w.of(band)
    ring = (np.abs(w.dist - target_r) < 0.004) if not upside_down else (w.dist < 0.8 * target_r)
    tops = top[ring & seen & (top > 0)]
    if tops.size == 0:
        return None
    inside = w.dist < 0.7 * rim_r
    outside = (w.dist > R + 0.007) & (w.dist < R + 0.013)
    return MugFit(
        spec=spec,
        x_m=w.centre[0],
        y_m=w.centre[1],
        radius_m=radius if free else target_r,
        height_m=float(np.median(tops)),
        upside_down=upside_down,
        support=_support(seen, w, target_r),
        residual_m=residual,
        free_radius=free,
        inside_fraction=float((top[inside] > 0.35 * h).mean()) if inside.any() else 0.0,
        outside_fraction=float((top[outside] >= h - 0.03).mean()) if outside.any() else 0.0,
        spill_m=_spill(w, w.of(filled), R) if upside_down else 0.0,
    )


def _spill(w: _Window, filled: BoolArray, radius: float) -> float:
    """How far the level surface holding the centre reaches past ``radius``: about 0 for the closed bottom
    of an upside-down mug, a third of the radius for the corners of a box. Thin bridges to neighbours (noise
    in the gap between two mugs) are opened first."""
    opened = cv2.morphologyEx(filled.astype(np.uint8), cv2.MORPH_OPEN, _DISC5)
    _, labels = cv2.connectedComponents(opened, connectivity=8)
    centre = np.unique(labels[(w.dist < 0.5 * radius) & (labels > 0)])
    surface = np.isin(labels, centre)
    return float(np.percentile(w.dist[surface], 97)) - radius if surface.any() else 0.0


def _support(seen: BoolArray, w: _Window, radius: float, samples: int = 48) -> float:
    """Fraction of directions from the centre along which ``seen`` has a cell within 4 mm of ``radius``."""
    near = seen & (np.abs(w.dist - radius) < 0.004)
    if not near.any():
        return 0.0
    dx, dy = w.gx[near], w.gy[near]
    return _coverage(dx, dy, sectors=samples)


def _coverage(dx: FloatArray, dy: FloatArray, sectors: int = 24) -> float:
    """Fraction of 15° sectors around the centre that hold brim cells."""
    a = np.floor((np.arctan2(dy, dx) + math.pi) / (2 * math.pi) * sectors).astype(np.int64) % sectors
    return float(np.count_nonzero(np.bincount(a, minlength=sectors))) / sectors


def _fit_circle(
    x: FloatArray, y: FloatArray, radius: float, *, free_radius: bool
) -> tuple[tuple[float, float], float, float]:
    """Geometric circle fit (Gauss-Newton, Huber weights) to points given relative to a first guess of the
    centre; the radius is held unless ``free_radius``. Returns the centre's offset, radius, RMS residual."""
    cx, cy, r = 0.0, 0.0, radius
    huber = 0.003
    for _ in range(8):
        dx, dy = x - cx, y - cy
        d = np.maximum(np.sqrt(dx * dx + dy * dy), 1e-9)
        ux, uy = dx / d, dy / d
        res = d - r
        w = np.minimum(1.0, huber / np.maximum(np.abs(res), 1e-12))
        wx, wy = w * ux, w * uy
        # Normal equations of the weighted problem; residual derivatives are (-ux, -uy, -1).
        a11, a12, a22 = float(wx @ ux), float(wx @ uy), float(wy @ uy)
        b1, b2 = float(wx @ res), float(wy @ res)
        if free_radius:
            a13, a23, a33, b3 = float(wx.sum()), float(wy.sum()), float(w.sum()), float(w @ res)
            step = _solve3((a11, a12, a13, a22, a23, a33), (b1, b2, b3))
        else:
            det = a11 * a22 - a12 * a12
            step = (
                None if abs(det) < 1e-18 else ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det, 0.0)
            )
        if step is None:
            break
        cx, cy, r = cx + step[0], cy + step[1], r + step[2]
        if step[0] * step[0] + step[1] * step[1] < 2.5e-9:  # under 50 µm: far below what the data resolve
            break
    dx, dy = x - cx, y - cy
    res = np.sqrt(dx * dx + dy * dy) - r
    return (cx, cy), r, float(np.sqrt(np.mean(res * res)))


def _solve3(
    a: tuple[float, float, float, float, float, float], b: tuple[float, float, float]
) -> tuple[float, float, float] | None:
    """Solve the symmetric 3×3 system [[a0 a1 a2] [a1 a3 a4] [a2 a4 a5]] x = b by Cramer's rule (numpy's
    solver costs more than the arithmetic at this size)."""
    a0, a1, a2, a3, a4, a5 = a
    c0 = a3 * a5 - a4 * a4
    c1 = a2 * a4 - a1 * a5
    c2 = a1 * a4 - a2 * a3
    det = a0 * c0 + a1 * c1 + a2 * c2
    if abs(det) < 1e-24:
        return None
    b0, b1, b2 = b
    x0 = (b0 * c0 + b1 * c1 + b2 * c2) / det
    x1 = (b0 * c1 + b1 * (a0 * a5 - a2 * a2) + b2 * (a1 * a2 - a0 * a4)) / det
    x2 = (b0 * c2 + b1 * (a1 * a2 - a0 * a4) + b2 * (a0 * a3 - a1 * a1)) / det
    return x0, x1, x2


def _handle_yaw(
    raster: _HeightMap,
    fit: MugFit,
    others: list[MugFit],
    camera_xy: FloatArray,
    p: DetectorParams,
) -> tuple[float, bool]:
    """Direction of the handle about +z in the table frame, and whether it was seen (else: pointing away)."""
    spec = fit.spec
    R = spec.diameter_mm / 2000.0
    reach = (spec.width_mm - spec.diameter_mm) / 1000.0
    h = spec.height_mm / 1000.0
    w = raster.window((fit.x_m, fit.y_m), R + reach + 0.01)
    top = w.of(raster.top)
    dist = w.dist
    cand = (dist > R + 0.009) & (dist < R + reach + 0.004) & (top > 0.15 * h) & (top < h - 0.012)
    gx, gy = w.gx, w.gy
    for o in others:
        ox, oy = o.x_m - fit.x_m, o.y_m - fit.y_m
        if math.hypot(ox, oy) < R + reach + o.radius_m + 0.03:
            cand &= np.hypot(gx - ox, gy - oy) > o.radius_m + 0.012
    away = math.atan2(fit.y_m - float(camera_xy[1]), fit.x_m - float(camera_xy[0]))
    if int(cand.sum()) < p.handle_min_cells:
        return away, False
    angles = np.arctan2(gy[cand], gx[cand])
    sectors = 36
    hist = np.bincount(
        (np.floor((angles + math.pi) / (2 * math.pi) * sectors).astype(np.int64) % sectors), minlength=sectors
    ).astype(np.float64)
    smooth = hist + np.roll(hist, 1) + np.roll(hist, -1)
    best = (np.argmax(smooth) + 0.5) / sectors * 2 * math.pi - math.pi
    near = np.abs(np.angle(np.exp(1j * (angles - best)))) < math.radians(35)
    if int(near.sum()) < p.handle_min_cells:
        return away, False
    yaw = math.atan2(float(np.sin(angles[near]).mean()), float(np.cos(angles[near]).mean()))
    return yaw, True


def _confidence(fit: MugFit, handle_seen: bool, p: DetectorParams) -> float:
    """0..1 from how much of the brim was seen, how round it is and how well height and size match."""
    h = fit.spec.height_mm / 1000.0
    dh = max(0.0, abs(fit.height_m - h) - 0.006) / p.height_tolerance_m
    target_r = fit.spec.diameter_mm / 2000.0 - (0.0 if fit.upside_down else RIM_INSET_M)
    dr = abs(fit.radius_m - target_r) / (p.diameter_tolerance_m / 2) if fit.free_radius else 0.5
    roundness = math.exp(-((fit.residual_m / 0.004) ** 2))
    score = min(1.0, fit.support / 0.75) * math.exp(-(dh**2) - 0.5 * dr**2) * (0.5 + 0.5 * roundness)
    return round(max(0.0, min(1.0, score * (1.0 if handle_seen else 0.85))), 4)


def _level_on_table(
    grid: _PixelGrid, world_from_camera: FloatArray, p: DetectorParams
) -> tuple[FloatArray, FloatArray]:
    """Fit the table plane near world z = 0: (table_from_world, xy of table points).

    The table frame turns the fitted plane level about the camera's centre and puts z = 0 on it. An error in
    the extrinsic's tilt (which is what tilts the plane) is a rotation about the camera, so this removes it
    and leaves x, y where a correct extrinsic would have put them. The xy returned are a sample of the
    plane's inliers, for sizing the search region.
    """
    # Every third pixel each way is plenty for a plane, at a ninth of the work.
    rx, ry, z, valid = grid.rx[::3, ::3], grid.ry[::3, ::3], grid.z[::3, ::3], grid.valid[::3, ::3]
    wz = _coordinate(world_from_camera, 2, rx, ry, z)
    idx = np.flatnonzero(valid & (np.abs(wz) < p.plane_prior_m))
    if len(idx) < 100:
        raise FrameError(_no_table(f"about {9 * len(idx)} points within {p.plane_prior_m} m of it"))
    rng = np.random.default_rng(p.seed)
    pick = idx[rng.integers(0, len(idx), size=min(p.ransac_sample, len(idx)))]
    rx, ry, z = rx.ravel()[pick], ry.ravel()[pick], z.ravel()[pick]
    sample = np.stack([_coordinate(world_from_camera, i, rx, ry, z) for i in range(3)], axis=1).astype(
        np.float64
    )
    # All RANSAC hypotheses at once: a plane through each random triple, scored by its inlier count.
    triples = rng.integers(0, len(sample), size=(p.ransac_iterations, 3))
    a, b, c = sample[triples[:, 0]], sample[triples[:, 1]], sample[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    level = norms > 1e-9
    normals[level] /= norms[level, None]
    level &= np.abs(normals[:, 2]) > 0.9  # the table is nearly level; steeper is a wall or a mug side
    if not level.any():
        raise FrameError(_no_table("no level surface among them"))
    normals, offsets = normals[level], np.einsum("ij,ij->i", normals[level], a[level])
    counts = (np.abs(sample @ normals.T - offsets) < p.plane_inlier_m).sum(axis=0)
    best = int(np.argmax(counts))
    if counts[best] < max(50, 0.3 * len(sample)):
        raise FrameError(
            _no_table(f"the best level plane holds only {counts[best]} of {len(sample)} sampled")
        )
    best_inliers = np.abs(sample @ normals[best] - offsets[best]) < p.plane_inlier_m
    q = sample[best_inliers]
    low, high = np.percentile(q[:, :2], [5, 95], axis=0)
    spread = high - low
    if spread.min() < p.min_table_extent_m:
        raise FrameError(_no_table(f"the level points span only {spread.min():.2f} m across"))
    centroid, normal = _plane_through(q)
    # Refit on the points that agree with the plane to within their own scatter: a tray base or a mat a few
    # millimetres proud of the table on one side would otherwise tilt the fit by a tenth of a degree, which
    # moves every centre by a millimetre.
    for _ in range(3):
        residual = (sample - centroid) @ normal
        scale = max(0.0015, 2.5 * 1.4826 * float(np.median(np.abs(residual[best_inliers]))))
        keep = np.abs(residual) < scale
        if keep.sum() < 50:
            break
        centroid, normal = _plane_through(sample[keep])
        best_inliers = keep
    R = _rotation_between(normal, np.array([0.0, 0.0, 1.0]))
    pivot = world_from_camera[:3, 3]
    table_from_world = np.eye(4)
    table_from_world[:3, :3] = R
    table_from_world[:3, 3] = pivot - R @ pivot
    table_from_world[2, 3] -= float((R @ (centroid - pivot))[2] + pivot[2])
    return table_from_world, q[:, :2]


def _plane_through(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares plane: its centroid and upward unit normal."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[2] if vt[2][2] > 0 else -vt[2]
    return centroid, normal


def _rotation_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """The smallest rotation taking unit vector ``a`` onto unit vector ``b`` (Rodrigues)."""
    v = np.cross(a, b)
    c = float(a @ b)
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return np.eye(3)
    k = v / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    out: FloatArray = np.eye(3) + s * K + (1 - c) * (K @ K)
    return out


def _region_around(table_xy: FloatArray) -> tuple[float, float, float, float]:
    """The bounding box of the table's points (capped to 3 m on a side), when no region is configured."""
    x0, y0 = np.percentile(table_xy, 0.5, axis=0)
    x1, y1 = np.percentile(table_xy, 99.5, axis=0)
    cxm, cym = (x0 + x1) / 2, (y0 + y1) / 2
    hx, hy = min((x1 - x0) / 2 + 0.05, 1.5), min((y1 - y0) / 2 + 0.05, 1.5)
    return float(cxm - hx), float(cym - hy), float(cxm + hx), float(cym + hy)


def _no_table(why: str) -> str:
    return f"no table plane in view near z = 0 ({why}); check the camera's world_from_camera"
