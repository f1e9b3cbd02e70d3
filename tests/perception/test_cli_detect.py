"""``dishbot detect`` on a rendered depth PNG and camera JSON, and every class of bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli.main import main
from description.cell import CellLayout, SceneMug
from description.thesis import BIG_MUG, SMALL_MUG
from perception.calibration import CameraModel
from sim.mujoco.camera import DepthNoise
from tests.perception.scenes import render


@pytest.fixture(scope="module")
def scene(layout: CellLayout, tmp_path_factory: pytest.TempPathFactory) -> tuple[list[SceneMug], Path, Path]:
    x0, y0, x1, y1 = layout.counter_region_m
    yc = (y0 + y1) / 2
    mugs = [
        SceneMug("a", BIG_MUG, x0 + 0.12, yc, yaw_rad=0.0),
        SceneMug("b", SMALL_MUG, (x0 + x1) / 2, yc, yaw_rad=0.4, upside_down=True),
        SceneMug("c", SMALL_MUG, x1 - 0.12, yc, yaw_rad=-0.3),
    ]
    frame = render(layout, mugs, noise=DepthNoise(), seed=4)
    d = tmp_path_factory.mktemp("detect")
    depth_png, camera_json = d / "depth.png", d / "camera.json"
    cv2.imwrite(str(depth_png), np.round(frame.depth_m * 1000.0).astype(np.uint16))
    camera_json.write_text(json.dumps(CameraModel(frame.intrinsics, frame.world_from_camera).to_json()))
    return mugs, depth_png, camera_json


def test_detect_prints_the_mugs_as_json(
    scene: tuple[list[SceneMug], Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    mugs, depth_png, camera_json = scene
    assert main(["detect", "--depth", str(depth_png), "--camera", str(camera_json), "--json"]) == 0
    found = json.loads(capsys.readouterr().out)["mugs"]
    assert len(found) == 3
    for mug in mugs:
        (hit,) = [m for m in found if math.hypot(m["x_m"] - mug.x_m, m["y_m"] - mug.y_m) < 0.005]
        assert hit["type"] == mug.spec.name
        assert hit["upside_down"] == mug.upside_down
        assert set(hit) == {
            "type",
            "x_m",
            "y_m",
            "upside_down",
            "handle_yaw_rad",
            "handle_seen",
            "confidence",
        }


def test_detect_prints_a_table_without_json(
    scene: tuple[list[SceneMug], Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    _, depth_png, camera_json = scene
    assert main(["detect", "--depth", str(depth_png), "--camera", str(camera_json)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "3 mug(s)"
    assert out[1].split() == ["type", "x_m", "y_m", "upside", "down", "handle", "°", "confidence"]
    assert len(out) == 5


def _fails(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    return err.strip()


def test_missing_depth_file_is_a_usage_error(
    scene: tuple[list[SceneMug], Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, _, camera_json = scene
    err = _fails(["detect", "--depth", str(tmp_path / "no.png"), "--camera", str(camera_json)], capsys)
    assert err == f"dishbot detect: error: depth image {tmp_path / 'no.png'}: no such file"


def test_eight_bit_depth_png_is_refused(
    scene: tuple[list[SceneMug], Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, _, camera_json = scene
    png = tmp_path / "rgb.png"
    cv2.imwrite(str(png), np.zeros((480, 640, 3), np.uint8))
    err = _fails(["detect", "--depth", str(png), "--camera", str(camera_json)], capsys)
    assert err == (
        f"dishbot detect: error: depth image {png}: expected a 16-bit single-channel PNG in millimetres, "
        "got 8-bit with 3 channel(s)"
    )


def test_depth_png_of_another_size_is_refused(
    scene: tuple[list[SceneMug], Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, _, camera_json = scene
    png = tmp_path / "small.png"
    cv2.imwrite(str(png), np.zeros((240, 320), np.uint16))
    err = _fails(["detect", "--depth", str(png), "--camera", str(camera_json)], capsys)
    assert err == (
        f"dishbot detect: error: depth image {png} is 320x240 pixels but the camera file says 640x480"
    )


def test_blank_depth_png_is_refused(
    scene: tuple[list[SceneMug], Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, _, camera_json = scene
    png = tmp_path / "blank.png"
    cv2.imwrite(str(png), np.zeros((480, 640), np.uint16))
    err = _fails(["detect", "--depth", str(png), "--camera", str(camera_json)], capsys)
    assert err == (
        f"dishbot detect: error: {png}: the depth image has only 0 valid pixels; is the camera covered?"
    )


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{", "is not valid JSON: Expecting property name enclosed in double quotes (line 1)"),
        ("[1, 2]", ": expected a JSON object, got list"),
        ('{"width": 640}', ": missing field 'height'"),
        (
            '{"width": 640, "height": 480, "fx": "x", "fy": 1, "cx": 1, "cy": 1, "world_from_camera": []}',
            ": field 'fx' must be a finite number, got 'x'",
        ),
        (
            '{"width": 640.5, "height": 480, "fx": 1, "fy": 1, "cx": 1, "cy": 1, "world_from_camera": []}',
            ": field 'width' must be a whole number of pixels in [16, 8192]",
        ),
        (
            '{"width": 640, "height": 480, "fx": 1, "fy": 1, "cx": 1, "cy": 1, "world_from_camera": [[1]]}',
            ": field 'world_from_camera' must be a 4x4 array of finite numbers",
        ),
        (
            '{"width": 640, "height": 480, "fx": 1, "fy": 1, "cx": 1, "cy": 1, "world_from_camera": '
            "[[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}",
            ": field 'world_from_camera' must be a rigid transform (rotation, translation, last row 0 0 0 1)",
        ),
    ],
)
def test_bad_camera_json_is_a_one_line_usage_error(
    scene: tuple[list[SceneMug], Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    content: str,
    message: str,
) -> None:
    _, depth_png, _ = scene
    camera = tmp_path / "camera.json"
    camera.write_text(content)
    err = _fails(["detect", "--depth", str(depth_png), "--camera", str(camera)], capsys)
    separator = " " if message.startswith("is") else ""
    assert err == f"dishbot detect: error: camera file {camera}{separator}{message}"
