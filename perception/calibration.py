"""Camera models and calibration: the camera JSON file, intrinsics from the config, extrinsics from a board.

The camera JSON (also written by ``dishbot calibrate`` and read by ``dishbot detect``) is::

    {"width": 640, "height": 480, "fx": …, "fy": …, "cx": …, "cy": …,
     "world_from_camera": [[…4×4…]]}

a pinhole camera looking along +z with x right and y down, pixel indices from the top-left pixel's centre.

Extrinsics come from a ChArUco board (a chessboard whose white squares hold ArUco markers, so every corner
is identified and a partly hidden board still works) lying flat on the table at a known place. OpenCV finds
the corners, ``solvePnP`` gives the board's pose in the camera, and the board's known pose in the world gives
the camera's.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from description.camera import CameraSpec
from drivers.interfaces import CameraIntrinsics, FloatArray
from perception.errors import BoardNotFound, CalibrationError

_INTRINSIC_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


@dataclass(frozen=True, slots=True)
class CameraModel:
    """Intrinsics and where the camera is: everything needed to turn its depth pixels into world points."""

    intrinsics: CameraIntrinsics
    world_from_camera: FloatArray

    def to_json(self) -> dict[str, object]:
        K = self.intrinsics
        return {
            "width": K.width,
            "height": K.height,
            "fx": K.fx,
            "fy": K.fy,
            "cx": K.cx,
            "cy": K.cy,
            "world_from_camera": [[round(float(v), 9) for v in row] for row in self.world_from_camera],
        }

    @classmethod
    def from_json(cls, obj: object, *, source: str = "camera JSON") -> CameraModel:
        """Validate the camera JSON format; ``CalibrationError`` names the source and the field."""
        if not isinstance(obj, Mapping):
            raise CalibrationError(f"{source}: expected a JSON object, got {type(obj).__name__}")
        missing = [k for k in (*_INTRINSIC_KEYS, "world_from_camera") if k not in obj]
        if missing:
            raise CalibrationError(f"{source}: missing field {missing[0]!r}")
        values: dict[str, float] = {}
        for key in _INTRINSIC_KEYS:
            v = obj[key]
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise CalibrationError(f"{source}: field {key!r} must be a finite number, got {v!r}")
            values[key] = float(v)
        for key in ("width", "height"):
            if not values[key].is_integer() or not 16 <= values[key] <= 8192:
                raise CalibrationError(
                    f"{source}: field {key!r} must be a whole number of pixels in [16, 8192]"
                )
        for key in ("fx", "fy"):
            if values[key] <= 0:
                raise CalibrationError(f"{source}: field {key!r} must be positive, got {values[key]}")
        T = _pose_matrix(obj["world_from_camera"], f"{source}: field 'world_from_camera'")
        K = CameraIntrinsics(
            int(values["width"]),
            int(values["height"]),
            values["fx"],
            values["fy"],
            values["cx"],
            values["cy"],
        )
        return cls(K, T)


def camera_model(
    *,
    width: int,
    height: int,
    fovy_deg: float,
    position_m: tuple[float, float, float],
    yaw_rad: float,
    pitch_rad: float,
    calibration_file: Path | None = None,
) -> CameraModel:
    """The camera as configured: a calibration file when one is given, else the ideal pinhole of the
    ``[camera]`` settings (square pixels, centred principal point, pose from position, yaw and pitch)."""
    if calibration_file is not None:
        model = load_camera_json(calibration_file)
        if (model.intrinsics.width, model.intrinsics.height) != (width, height):
            raise CalibrationError(
                f"camera file {calibration_file} is for {model.intrinsics.width}x{model.intrinsics.height} "
                f"images but the camera is configured for {width}x{height}"
            )
        return model
    spec = CameraSpec(width, height, fovy_deg, position_m, yaw_rad, pitch_rad)
    return CameraModel(spec.intrinsics(), spec.world_from_camera())


def load_camera_json(path: Path) -> CameraModel:
    """Read a camera JSON file; ``CalibrationError`` says which file and what is wrong with it."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise CalibrationError(f"cannot read camera file {path}: {e.strerror}") from e
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        raise CalibrationError(f"camera file {path} is not valid JSON: {e.msg} (line {e.lineno})") from e
    return CameraModel.from_json(obj, source=f"camera file {path}")


def _pose_matrix(value: object, what: str) -> FloatArray:
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise CalibrationError(f"{what} must be a 4x4 array of numbers") from e
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise CalibrationError(f"{what} must be a 4x4 array of finite numbers")
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6) or not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
        raise CalibrationError(f"{what} must be a rigid transform (rotation, translation, last row 0 0 0 1)")
    if np.linalg.det(R) < 0:
        raise CalibrationError(f"{what} is a reflection, not a rotation (determinant -1)")
    return T


@dataclass(frozen=True, slots=True)
class CharucoBoard:
    """A ChArUco board: ``squares_x`` × ``squares_y`` squares of ``square_m``, markers of ``marker_m``.

    The default (6 × 4 squares of 7 cm) prints on A3 and is large enough for a 640×480 camera 1–2 m away.
    Board frame: origin at the printed image's top-left corner, x along its width, y down its height, z into
    the paper.
    """

    squares_x: int = 6
    squares_y: int = 4
    square_m: float = 0.07
    marker_m: float = 0.052
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise CalibrationError(f"board {self.squares_x}x{self.squares_y}: use at least 3x3 squares")
        if not 0 < self.marker_m < self.square_m:
            raise CalibrationError(
                f"board marker size {self.marker_m} m must be positive and smaller than the square "
                f"({self.square_m} m)"
            )
        if not hasattr(cv2.aruco, self.dictionary):
            raise CalibrationError(
                f"unknown ArUco dictionary {self.dictionary!r}; e.g. DICT_4X4_50, DICT_5X5_100"
            )

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def opencv(self) -> Any:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary
        )

    def image(self, *, px_per_square: int = 200) -> npt.NDArray[np.uint8]:
        """The board as a grey image to print (or to texture a simulated board with)."""
        size = (self.squares_x * px_per_square, self.squares_y * px_per_square)
        out: npt.NDArray[np.uint8] = self.opencv().generateImage(size)
        return out


def board_on_table(x_m: float, y_m: float, yaw_rad: float = 0.0) -> FloatArray:
    """world_from_board of a board lying face up with its top-left corner at (x, y) and its width along
    ``yaw_rad``; its height then runs to the right of that direction, and its z points into the table."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    T = np.eye(4)
    T[:3, 0] = (c, s, 0.0)
    T[:3, 1] = (s, -c, 0.0)
    T[:3, 2] = (0.0, 0.0, -1.0)
    T[:3, 3] = (x_m, y_m, 0.0)
    return T


@dataclass(frozen=True, slots=True)
class ExtrinsicCalibration:
    """The camera's pose found from a board, with how well the board's corners fit it."""

    world_from_camera: FloatArray
    reprojection_rms_px: float
    corners: int


def calibrate_extrinsics(
    image: npt.NDArray[np.uint8],
    intrinsics: CameraIntrinsics,
    board: CharucoBoard,
    world_from_board: FloatArray,
    *,
    min_corners: int = 6,
    upsample: int = 3,
) -> ExtrinsicCalibration:
    """The camera's world pose from one image of ``board`` lying at ``world_from_board``.

    The image is enlarged ``upsample`` times before the search: at 640×480 a board 1.5 m away has markers a
    dozen pixels across, below what the ArUco decoder reads reliably.
    """
    K = intrinsics
    if image.shape[:2] != (K.height, K.width):
        raise CalibrationError(
            f"the board image is {image.shape[1]}x{image.shape[0]} pixels but the camera is "
            f"{K.width}x{K.height}"
        )
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    big = cv2.resize(gray, None, fx=upsample, fy=upsample, interpolation=cv2.INTER_CUBIC)
    cv_board = board.opencv()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(cv_board).detectBoard(big)
    found = 0 if ids is None else len(ids)
    if found < min_corners:
        raise BoardNotFound(
            f"found {found} board corners, need at least {min_corners}: is the whole board in view, lit and "
            f"flat, and is it the {board.squares_x}x{board.squares_y} {board.dictionary} board?"
        )
    object_points, image_points = cv_board.matchImagePoints(corners, ids)
    image_points = (image_points + 0.5) / upsample - 0.5  # back to the camera's pixel indices
    camera_matrix = np.array([[K.fx, 0.0, K.cx], [0.0, K.fy, K.cy], [0.0, 0.0, 1.0]])
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera_matrix, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise BoardNotFound("the board's corners gave no pose (solvePnP failed); take another image")
    rvec, tvec = cv2.solvePnPRefineLM(object_points, image_points, camera_matrix, None, rvec, tvec)
    projected, _ = cv2.projectPoints(object_points, rvec, tvec, camera_matrix, None)
    residuals = projected.reshape(-1, 2) - image_points.reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    camera_from_board = np.eye(4)
    camera_from_board[:3, :3] = cv2.Rodrigues(rvec)[0]
    camera_from_board[:3, 3] = tvec.ravel()
    world_from_camera = np.asarray(world_from_board @ np.linalg.inv(camera_from_board), dtype=np.float64)
    return ExtrinsicCalibration(world_from_camera, rms, found)
