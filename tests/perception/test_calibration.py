"""Extrinsic calibration from a rendered ChArUco board on the simulated table, and the camera model."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pytest

from cli.main import main
from description.cell import CellLayout
from perception.calibration import (
    CharucoBoard,
    board_on_table,
    calibrate_extrinsics,
    camera_model,
    load_camera_json,
)
from perception.errors import BoardNotFound, CalibrationError
from sim.mujoco.camera import DepthCamera
from sim.mujoco.scene import build_mjcf, calibration_board_xml

BOARD = CharucoBoard()
ORIGIN = (-0.21, 0.56)
YAW = 0.15


def _rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    r = a[:3, :3].T @ b[:3, :3]
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))


@pytest.fixture(scope="module")
def board_shot(
    layout: CellLayout, tmp_path_factory: pytest.TempPathFactory
) -> tuple[np.ndarray, np.ndarray, Path]:
    """A colour image of the board lying on the counter, the true camera pose, and the image as a PNG."""
    ok, png = cv2.imencode(".png", BOARD.image(px_per_square=120))
    assert ok
    assets, body = calibration_board_xml(BOARD.size_m, ORIGIN, YAW, texture_file="board.png")
    xml = build_mjcf(layout, [], extra_assets=assets, extra_body_xml=body)
    model = mujoco.MjModel.from_xml_string(xml, {"board.png": png.tobytes()})
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with DepthCamera(model, data, color=True) as camera:
        frame = camera.render()
    assert frame.color is not None
    path = tmp_path_factory.mktemp("calib") / "board.png"
    cv2.imwrite(str(path), cv2.cvtColor(frame.color, cv2.COLOR_RGB2BGR))
    return frame.color, frame.world_from_camera, path


def test_board_pose_gives_the_camera_pose(
    board_shot: tuple[np.ndarray, np.ndarray, Path], layout: CellLayout
) -> None:
    image, truth, _ = board_shot
    result = calibrate_extrinsics(image, layout.camera.intrinsics(), BOARD, board_on_table(*ORIGIN, YAW))
    assert result.corners >= 8
    assert result.reprojection_rms_px < 0.5
    assert np.linalg.norm(result.world_from_camera[:3, 3] - truth[:3, 3]) < 0.01
    assert _rotation_error_deg(result.world_from_camera, truth) < 0.3


def test_calibrate_cli_writes_a_camera_file_detect_can_read(
    board_shot: tuple[np.ndarray, np.ndarray, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, truth, png = board_shot
    out = tmp_path / "camera.json"
    args = ["calibrate", "--image", str(png), "--board-origin", str(ORIGIN[0]), str(ORIGIN[1])]
    assert main([*args, "--board-yaw", str(YAW), "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["corners"] >= 8
    model = load_camera_json(out)
    assert (model.intrinsics.width, model.intrinsics.height) == (640, 480)
    assert np.linalg.norm(model.world_from_camera[:3, 3] - truth[:3, 3]) < 0.01


def test_an_image_without_the_board_is_refused(layout: CellLayout) -> None:
    blank = np.full((480, 640), 180, np.uint8)
    with pytest.raises(
        BoardNotFound, match=r"^found 0 board corners, need at least 6: is the whole board in view"
    ):
        calibrate_extrinsics(blank, layout.camera.intrinsics(), BOARD, board_on_table(0.0, 0.0))


def test_calibrate_cli_without_board_in_view_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "grey.png"
    cv2.imwrite(str(png), np.full((480, 640), 180, np.uint8))
    assert main(["calibrate", "--image", str(png), "--board-origin", "0", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"dishbot calibrate: error: --image {png}: found 0 board corners")
    assert err.count("\n") == 1


def test_calibrate_cli_needs_the_board_origin(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "--image", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == (
        "dishbot calibrate: error: --board-origin X Y is required with --image: where the board's top-left "
        "corner lies\n"
    )


def test_calibrate_cli_refuses_a_malformed_board(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "--write-board", "b.png", "--board", "six-by-four"]) == 2
    assert (
        capsys.readouterr().err
        == "dishbot calibrate: error: --board 'six-by-four': expected COLSxROWS, e.g. 6x4\n"
    )


def test_write_board_writes_the_printable_board(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "board.png"
    assert main(["calibrate", "--write-board", str(out)]) == 0
    assert capsys.readouterr().out == f"wrote {out}: print it 42 cm x 28 cm\n"
    board = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert board is not None
    assert board.shape == (800, 1200)


def test_markers_as_large_as_squares_are_refused() -> None:
    with pytest.raises(
        CalibrationError, match=r"^board marker size 0.07 m must be positive and smaller than the square"
    ):
        CharucoBoard(square_m=0.07, marker_m=0.07)


def test_configured_camera_model_matches_the_rendered_camera(layout: CellLayout) -> None:
    c = layout.camera
    model = camera_model(
        width=c.width,
        height=c.height,
        fovy_deg=c.fovy_deg,
        position_m=c.position_m,
        yaw_rad=c.yaw_rad,
        pitch_rad=c.pitch_rad,
    )
    assert model.intrinsics == c.intrinsics()
    np.testing.assert_allclose(model.world_from_camera, c.world_from_camera())


def test_calibration_file_of_another_resolution_is_refused(tmp_path: Path, layout: CellLayout) -> None:
    c = layout.camera
    path = tmp_path / "cam.json"
    doc = {
        "width": 320,
        "height": 240,
        "fx": 200,
        "fy": 200,
        "cx": 160,
        "cy": 120,
        "world_from_camera": np.eye(4).tolist(),
    }
    path.write_text(json.dumps(doc))
    with pytest.raises(
        CalibrationError, match=r"is for 320x240 images but the camera is configured for 640x480$"
    ):
        camera_model(
            width=640,
            height=480,
            fovy_deg=c.fovy_deg,
            position_m=c.position_m,
            yaw_rad=c.yaw_rad,
            pitch_rad=c.pitch_rad,
            calibration_file=path,
        )
