"""``dishbot calibrate``: the depth camera's pose from one image of a ChArUco board lying on the table."""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.config import load_config
from daemon.errors import UsageError

if TYPE_CHECKING:
    import numpy.typing as npt

    from perception.calibration import CameraModel, CharucoBoard

_BOARD = re.compile(r"^(\d+)x(\d+)\Z")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "calibrate",
        help="find the camera's pose from an image of a ChArUco board on the table",
        description=(
            "Lay the printed ChArUco board flat on the table with its top-left corner (as printed) at "
            "--board-origin and its width along --board-yaw, take one image with the camera, and run this. "
            "It finds the board's corners, solves the camera's pose and writes a camera JSON (the format "
            "`dishbot detect --camera` reads; point [camera] calibration_file at it). Intrinsics come from "
            "--camera or from the config's [camera]. --write-board prints the board image to use instead."
        ),
    )
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument(
        "--image", type=Path, metavar="FILE.png", help="the camera's image of the board (colour or grey)"
    )
    mode.add_argument(
        "--write-board", type=Path, metavar="FILE.png", help="write the board image to print, then exit"
    )
    parser.add_argument(
        "--camera",
        type=Path,
        metavar="CAMERA.json",
        help="intrinsics from this camera JSON instead of the config",
    )
    parser.add_argument(
        "--config", type=Path, metavar="FILE", help="config file whose [camera] gives intrinsics"
    )
    parser.add_argument(
        "--board-origin",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="world position (m) of the board's printed top-left corner; required with --image",
    )
    parser.add_argument(
        "--board-yaw", type=float, default=0.0, metavar="RAD", help="direction of the board's width"
    )
    parser.add_argument(
        "--board", default="6x4", metavar="COLSxROWS", help="squares across and down (default 6x4)"
    )
    parser.add_argument(
        "--square-m", type=float, default=0.07, metavar="M", help="printed square size (default 0.07)"
    )
    parser.add_argument(
        "--marker-m", type=float, default=0.052, metavar="M", help="printed marker size (default 0.052)"
    )
    parser.add_argument("--dictionary", default="DICT_4X4_50", help="ArUco dictionary (default DICT_4X4_50)")
    parser.add_argument(
        "--out", type=Path, metavar="CAMERA.json", help="write the calibrated camera JSON here"
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from perception.calibration import CameraModel, board_on_table, calibrate_extrinsics
    from perception.errors import PerceptionError

    board = _board(args)
    if args.write_board is not None:
        if not cv2.imwrite(str(args.write_board), board.image()):
            raise UsageError(f"--write-board: cannot write {args.write_board}")
        w, h = board.size_m
        print(f"wrote {args.write_board}: print it {w * 100:.0f} cm x {h * 100:.0f} cm")
        return 0
    if args.board_origin is None:
        raise UsageError(
            "--board-origin X Y is required with --image: where the board's top-left corner lies"
        )
    camera = _intrinsics(args)
    image = cv2.imread(str(args.image), cv2.IMREAD_UNCHANGED) if args.image.is_file() else None
    if image is None:
        raise UsageError(f"--image {args.image}: no such file or not a readable image")
    if image.dtype != np.uint8:
        raise UsageError(f"--image {args.image}: expected an 8-bit image, got {image.dtype.itemsize * 8}-bit")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    gray: npt.NDArray[np.uint8] = np.asarray(image, dtype=np.uint8)
    world_from_board = board_on_table(args.board_origin[0], args.board_origin[1], args.board_yaw)
    try:
        result = calibrate_extrinsics(gray, camera.intrinsics, board, world_from_board)
    except PerceptionError as e:
        raise UsageError(f"--image {args.image}: {e}") from e
    calibrated = CameraModel(camera.intrinsics, result.world_from_camera)
    doc = {
        **calibrated.to_json(),
        "reprojection_rms_px": round(result.reprojection_rms_px, 4),
        "corners": result.corners,
    }
    if args.out is not None:
        try:
            args.out.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        except OSError as e:
            raise UsageError(f"--out {args.out}: cannot write ({e.strerror})") from e
    if args.json:
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    T = result.world_from_camera
    forward = T[:3, 2]
    print(f"board corners used: {result.corners}, reprojection RMS {result.reprojection_rms_px:.3f} px")
    print(f"camera position (m): {T[0, 3]:.4f} {T[1, 3]:.4f} {T[2, 3]:.4f}")
    print(
        f"looking: yaw {math.degrees(math.atan2(forward[1], forward[0])):.2f}°, "
        f"pitch {math.degrees(-math.asin(max(-1.0, min(1.0, forward[2])))):.2f}° below the horizon"
    )
    if args.out is not None:
        print(f"wrote {args.out}")
    return 0


def _board(args: argparse.Namespace) -> CharucoBoard:
    from perception.calibration import CharucoBoard
    from perception.errors import PerceptionError

    m = _BOARD.match(args.board)
    if m is None:
        raise UsageError(f"--board {args.board!r}: expected COLSxROWS, e.g. 6x4")
    try:
        return CharucoBoard(int(m.group(1)), int(m.group(2)), args.square_m, args.marker_m, args.dictionary)
    except PerceptionError as e:
        raise UsageError(str(e)) from e


def _intrinsics(args: argparse.Namespace) -> CameraModel:
    from perception.calibration import camera_model, load_camera_json
    from perception.errors import PerceptionError

    try:
        if args.camera is not None:
            return load_camera_json(args.camera)
        c = load_config(args.config).cell.camera
        return camera_model(
            width=c.width,
            height=c.height,
            fovy_deg=c.fovy_deg,
            position_m=c.position_m,
            yaw_rad=c.yaw_rad,
            pitch_rad=c.pitch_rad,
        )
    except PerceptionError as e:
        raise UsageError(str(e)) from e
