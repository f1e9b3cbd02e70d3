"""``dishbot detect``: the mugs in one depth image (a 16-bit PNG in millimetres) from a described camera."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.config import load_config
from daemon.errors import UsageError

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from perception.calibration import CameraModel
    from perception.interfaces import Detection


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "detect",
        help="detect the mugs in a depth image",
        description=(
            "Run the depth mug detector on one depth image with the configured mug catalogue. Prints each "
            "mug's type, brim centre on the table (world frame, metres), whether it stands upside down, its "
            "handle direction and a confidence."
        ),
    )
    parser.add_argument(
        "--depth",
        type=Path,
        required=True,
        metavar="FILE.png",
        help="16-bit single-channel PNG, depth along the optical axis in millimetres, 0 = no reading",
    )
    parser.add_argument(
        "--camera",
        type=Path,
        required=True,
        metavar="CAMERA.json",
        help='camera JSON: {"width", "height", "fx", "fy", "cx", "cy", "world_from_camera": 4x4} (pinhole, '
        "looking along +z, x right, y down)",
    )
    parser.add_argument("--config", type=Path, metavar="FILE", help="config file whose [mug_types] to use")
    parser.add_argument(
        "--json", action="store_true", help='print {"mugs": [...]} as JSON instead of a table'
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from drivers.interfaces import RGBDFrame
    from perception.detector import DepthMugDetector
    from perception.errors import PerceptionError

    camera = _camera(args.camera)
    depth = read_depth_png(args.depth, camera)
    config = load_config(args.config)
    frame = RGBDFrame(0.0, depth, camera.intrinsics, camera.world_from_camera)  # a file has no capture time
    try:
        mugs = DepthMugDetector(config.mug_catalogue()).detect(frame)
    except PerceptionError as e:
        raise UsageError(f"{args.depth}: {e}") from e
    _print(mugs, as_json=args.json)
    return 0


def _camera(path: Path) -> CameraModel:
    from perception.calibration import load_camera_json
    from perception.errors import PerceptionError

    try:
        return load_camera_json(path)
    except PerceptionError as e:
        raise UsageError(str(e)) from e


def read_depth_png(path: Path, camera: CameraModel) -> npt.NDArray[np.float32]:
    """The depth image in metres (0 = no reading); ``UsageError`` when it is not what the camera produces."""
    import cv2
    import numpy as np

    if not path.is_file():
        raise UsageError(f"depth image {path}: no such file")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise UsageError(f"depth image {path}: not a readable PNG")
    if image.dtype != np.uint16 or image.ndim != 2:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise UsageError(
            f"depth image {path}: expected a 16-bit single-channel PNG in millimetres, "
            f"got {image.dtype.itemsize * 8}-bit with {channels} channel(s)"
        )
    K = camera.intrinsics
    if image.shape != (K.height, K.width):
        raise UsageError(
            f"depth image {path} is {image.shape[1]}x{image.shape[0]} pixels but the camera file says "
            f"{K.width}x{K.height}"
        )
    return (image.astype(np.float32) / np.float32(1000.0)).astype(np.float32)


def _print(mugs: list[Detection], *, as_json: bool) -> None:
    if as_json:
        rows = [
            {
                "type": d.type,
                "x_m": round(d.x_m, 4),
                "y_m": round(d.y_m, 4),
                "upside_down": d.upside_down,
                "handle_yaw_rad": round(d.handle_yaw_rad, 4),
                "handle_seen": d.handle_seen,
                "confidence": round(d.confidence, 3),
            }
            for d in mugs
        ]
        json.dump({"mugs": rows}, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return
    print(f"{len(mugs)} mug(s)")
    if mugs:
        print(f"{'type':<8}{'x_m':>9}{'y_m':>9}  {'upside down':<12}{'handle °':>9}{'confidence':>12}")
    for d in mugs:
        print(
            f"{d.type:<8}{d.x_m:>9.4f}{d.y_m:>9.4f}  {'yes' if d.upside_down else 'no':<12}"
            f"{math.degrees(d.handle_yaw_rad):>9.1f}{d.confidence:>12.3f}"
        )
