"""The pictures the verbs write: whole, with the mode any new file gets, and saying in their PNG text what
they show (tested by that text and the file's metadata, not by pixels)."""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli.main import main
from cli.pictures import png_text, png_with_text


@pytest.fixture
def umask() -> Iterator[None]:
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def test_text_chunks_go_into_a_png_that_still_decodes_and_come_back_out() -> None:
    ok, encoded = cv2.imencode(".png", np.zeros((4, 6, 3), np.uint8))
    assert ok
    png = png_with_text(encoded.tobytes(), {"Title": "tray 332 x 374 mm", "Description": "a\nb"})
    assert png_text(png) == {"Title": "tray 332 x 374 mm", "Description": "a\nb"}
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)  # CRCs right
    assert image is not None
    assert image.shape == (4, 6, 3)
    with pytest.raises(ValueError, match="not a PNG"):
        png_with_text(b"GIF89a", {})


def test_plan_pictures_get_the_usual_file_mode_and_the_png_names_tray_size_units_and_mugs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], umask: None
) -> None:
    png, svg = tmp_path / "plan.png", tmp_path / "plan.svg"
    assert (
        main(["plan", "--dataset", "1", "--method", "bh", "--png", str(png), "--svg", str(svg), "--json"])
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert stat.S_IMODE(png.stat().st_mode) == 0o644
    assert stat.S_IMODE(svg.stat().st_mode) == 0o644
    text = png_text(png.read_bytes())
    assert text["Title"] == f"dishbot plan: bh, {result['n']} of 12 mugs on the tray"
    description = text["Description"]
    assert "Top view of the tray, 332 x 374 mm" in description
    assert "lengths in mm" in description
    for p in result["placed"]:
        assert f"{p['order']} {p['id']} ({p['type']}) at x {p['x_mm']} y {p['y_mm']} mm" in description
    assert "left on the counter: " + ", ".join(result["unplaced"]) in description
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.png", "plan.svg"]  # no temporary left


def test_a_tighter_umask_is_respected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old = os.umask(0o027)
    try:
        png = tmp_path / "plan.png"
        assert main(["plan", "--dataset", "2", "--png", str(png)]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(png.stat().st_mode) == 0o640


@pytest.mark.slow
def test_the_workspace_picture_has_a_title_axes_in_mm_a_scale_and_a_legend(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], umask: None
) -> None:
    png = tmp_path / "ws.png"
    assert main(["arm", "workspace", "--png", str(png), "--json"]) == 0
    carry_m = json.loads(capsys.readouterr().out)["carry_height_m"]
    assert stat.S_IMODE(png.stat().st_mode) == 0o644
    text = png_text(png.read_bytes())
    assert text["Title"] == f"dishbot arm workspace: top view at the carry height {carry_m * 100:.1f} cm"
    drawn = text["Description"].splitlines()
    assert {"x (mm, forward)", "y (mm, to the arm's left)"} <= set(drawn)  # the axes, named with units
    ticks = [int(t) for t in drawn if t.lstrip("-").isdigit()]
    assert sorted(set(ticks)) == list(range(-800, 801, 200))  # along both axes
    assert ticks.count(0) == 2
    assert "100 mm" in drawn  # the scale bar
    legend = drawn[drawn.index("legend") + 1 :]
    assert legend[:5] == [
        "pick reachable: side grasp, every mug type",
        "place reachable: upside-down grasp",
        "pick and place reachable",
        "counter region (mugs start here)",
        "tray",
    ]
    assert {"counter region", "tray", "flip area"} <= set(drawn[: drawn.index("legend")])  # on the map
    image = cv2.imread(str(png))
    assert image is not None
    assert image.shape[1] > image.shape[0]  # the legend beside the map
