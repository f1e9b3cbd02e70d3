"""A simulated structured-light depth camera: MuJoCo renders depth, a sensor model spoils it like a real one.

The model follows the Kinect/Xtion class of sensors the thesis used (§5.3.3: an ASUS Xtion Pro Live): depth
comes from the disparity between a projector and a camera, so the random error grows with the square of the
distance, the disparity is quantised (a fraction of a pixel), and pixels are lost at depth discontinuities, at
grazing angles and beyond the working range. Depth is planar z in metres along the optical axis; 0 means no
reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

import mujoco
import numpy as np
import numpy.typing as npt

from drivers.interfaces import CameraIntrinsics, FloatArray, RGBDFrame


@dataclass(frozen=True, slots=True)
class DepthNoise:
    """Structured-light depth error: sigma(z) = sigma_at_1m_m · z², disparity quantisation, dropouts.

    Defaults are Kinect-v1-class figures (Khoshelham & Elberink 2012: about 1.5 mm at 1 m; 7.5 cm baseline,
    1/8-pixel disparity steps at a 580 px focal length, 0.5–4 m range).
    """

    sigma_at_1m_m: float = 0.0015
    baseline_m: float = 0.075
    focal_px: float = 580.0
    disparity_step_px: float = 0.125
    min_range_m: float = 0.5
    max_range_m: float = 4.0
    edge_jump_m: float = 0.03  # a depth step larger than this loses the pixel on its far side ...
    edge_dropout: float = 0.7  # ... with this probability (the projector's pattern is shadowed there)
    random_dropout: float = 0.003

    def __post_init__(self) -> None:
        for name in ("sigma_at_1m_m", "disparity_step_px", "edge_dropout", "random_dropout"):
            if getattr(self, name) < 0:
                raise ValueError(f"DepthNoise.{name} must not be negative, got {getattr(self, name)}")
        if self.baseline_m <= 0 or self.focal_px <= 0:
            raise ValueError("DepthNoise.baseline_m and focal_px must be positive")

    def apply(self, depth_m: npt.NDArray[np.float32], rng: np.random.Generator) -> npt.NDArray[np.float32]:
        """A noisy copy of an ideal planar depth image (0 stays 0). Single precision: the steps it models
        are millimetres, and it runs on every simulated frame."""
        z = np.asarray(depth_m, dtype=np.float32)
        valid = (z >= self.min_range_m) & (z <= self.max_range_m)
        noisy = z + rng.standard_normal(z.shape, dtype=np.float32) * (np.float32(self.sigma_at_1m_m) * z * z)
        if self.disparity_step_px > 0:
            fb = np.float32(self.focal_px * self.baseline_m)
            step = np.float32(self.disparity_step_px)
            disparity = np.round(fb / np.where(valid, noisy, np.float32(1.0)) / step) * step
            noisy = (fb / np.maximum(disparity, np.float32(1e-6))).astype(np.float32)
        # One uniform draw serves both dropouts: a pixel is lost at random, or more often behind an edge.
        u = rng.random(z.shape, dtype=np.float32)
        lost = u < self.random_dropout
        if self.edge_dropout > 0:
            lost |= _far_side_of_edges(z, self.edge_jump_m) & (u < self.edge_dropout)
        out: npt.NDArray[np.float32] = np.where(valid & ~lost, noisy, np.float32(0.0)).astype(np.float32)
        return out


def _far_side_of_edges(z: npt.NDArray[np.float32], jump_m: float) -> npt.NDArray[np.bool_]:
    """Pixels that are more than ``jump_m`` farther than one of their 4-neighbours."""
    edge = np.zeros(z.shape, dtype=bool)
    dv = z[1:, :] - z[:-1, :]
    du = z[:, 1:] - z[:, :-1]
    edge[1:, :] |= dv > jump_m
    edge[:-1, :] |= -dv > jump_m
    edge[:, 1:] |= du > jump_m
    edge[:, :-1] |= -du > jump_m
    return edge


# MuJoCo cameras look along their -z with y up; the pinhole convention looks along +z with y down.
_MJ_TO_PINHOLE = np.diag([1.0, -1.0, -1.0])


class DepthCamera:
    """Renders the named MuJoCo camera as a depth camera; implements ``drivers.interfaces.Camera``.

    Use as a context manager (or call ``close``) to release the offscreen GL context. ``render`` is
    synchronous and must run on the thread that created the camera; ``capture`` is the async protocol method.
    The camera reads poses from ``data`` as they are: forward or step the model before rendering. A frame's
    ``t`` is the simulated time of the state it shows (``data.time``).
    """

    def __init__(
        self,
        model: Any,
        data: Any,
        *,
        camera_name: str = "depth_camera",
        width: int = 640,
        height: int = 480,
        noise: DepthNoise | None = None,
        seed: int = 0,
        color: bool = False,
    ) -> None:
        cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera_name)
        if cam_id < 0:
            raise ValueError(f"the model has no camera named {camera_name!r}; add it to the MJCF")
        self._model = model
        self._data = data
        self._camera_name = camera_name
        self._cam_id = cam_id
        self._noise = noise
        self._rng = np.random.default_rng(seed)
        self._color = color
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        self._far_m = float(model.vis.map.zfar * model.stat.extent)
        f = (height / 2.0) / math.tan(math.radians(float(model.cam_fovy[cam_id])) / 2.0)
        self.intrinsics = CameraIntrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    def world_from_camera(self) -> FloatArray:
        """The camera's present pose (pinhole convention) from MuJoCo's camera frame."""
        T = np.eye(4)
        T[:3, :3] = self._data.cam_xmat[self._cam_id].reshape(3, 3) @ _MJ_TO_PINHOLE
        T[:3, 3] = self._data.cam_xpos[self._cam_id]
        return T

    def render(self) -> RGBDFrame:
        """Render one frame now (depth, plus colour when enabled) with the noise model applied."""
        if self._renderer is None:
            raise RuntimeError(f"camera {self._camera_name!r} is closed")
        if not np.any(self._data.cam_xpos[self._cam_id]):
            raise RuntimeError(
                "the MjData has no poses yet: call mujoco.mj_forward (or mj_step) before rendering"
            )
        r = self._renderer
        r.enable_depth_rendering()
        r.update_scene(self._data, camera=self._cam_id)
        depth = r.render()
        r.disable_depth_rendering()
        depth = np.where(depth < self._far_m * 0.999, depth, 0.0).astype(np.float32)
        if self._noise is not None:
            depth = self._noise.apply(depth, self._rng)
        rgb: npt.NDArray[np.uint8] | None = None
        if self._color:
            rgb = r.render().copy()
        return RGBDFrame(
            t=float(self._data.time),
            depth_m=depth,
            intrinsics=self.intrinsics,
            world_from_camera=self.world_from_camera(),
            color=rgb,
            meta={"camera": self._camera_name, "sim_time_s": f"{float(self._data.time):.6f}"},
        )

    async def capture(self) -> RGBDFrame:
        """The protocol method. Rendering holds the GL context of the creating thread, so it runs inline."""
        return self.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
