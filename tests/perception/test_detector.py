"""The depth mug detector on rendered, noisy frames of the simulated cell."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from description.cell import CellLayout, SceneMug
from description.thesis import BIG_MUG, MUG_TYPES, SMALL_MUG
from drivers.interfaces import RGBDFrame
from perception.detector import DepthMugDetector
from perception.errors import FrameError
from sim.mujoco.camera import DepthNoise
from sim.scoring import clutter_xml, dataset_mugs, score_frame
from tests.perception.scenes import render


@pytest.fixture(scope="module")
def detector(layout: CellLayout) -> DepthMugDetector:
    return DepthMugDetector(MUG_TYPES, region_m=layout.table_region_m)


@pytest.fixture(scope="module")
def dataset_1(layout: CellLayout) -> tuple[list[SceneMug], RGBDFrame]:
    mugs = dataset_mugs(1, layout, MUG_TYPES, seed=3)
    return mugs, render(layout, mugs, extra_body_xml=clutter_xml(layout), noise=DepthNoise(), seed=3)


@pytest.fixture(scope="module")
def odd_places(layout: CellLayout) -> tuple[list[SceneMug], RGBDFrame]:
    """An upside-down mug on the flip area, one in the tray, one on the counter, its handle to the side."""
    fx, fy = layout.flip_area_center_m
    tx0, ty0, tx1, ty1 = layout.tray.region_m
    cx0, cy0, cx1, cy1 = layout.counter_region_m
    mugs = [
        SceneMug("flip", BIG_MUG, fx, fy, yaw_rad=0.3, upside_down=True),
        SceneMug("tray", SMALL_MUG, (tx0 + tx1) / 2, (ty0 + ty1) / 2, yaw_rad=0.0),
        SceneMug("side", SMALL_MUG, (cx0 + cx1) / 2, (cy0 + cy1) / 2, yaw_rad=math.pi / 2),
    ]
    return mugs, render(layout, mugs, noise=DepthNoise(), seed=5)


def test_every_mug_of_a_dataset_is_found_with_its_type(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = dataset_1
    score = score_frame(mugs, detector.detect(frame))
    assert (score.true_positives, score.false_positives, score.false_negatives) == (12, 0, 0)
    assert score.type_correct == 12
    assert score.upside_down_correct == 12


def test_mug_centres_are_millimetre_accurate(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = dataset_1
    errors = np.array(score_frame(mugs, detector.detect(frame)).centre_errors_m)
    assert np.median(errors) < 0.003
    assert errors.max() < 0.006


def test_balls_and_boxes_on_an_empty_counter_are_not_mugs(
    detector: DepthMugDetector, layout: CellLayout
) -> None:
    frame = render(layout, [], extra_body_xml=clutter_xml(layout), noise=DepthNoise(), seed=1)
    assert detector.detect(frame) == []


def test_upside_down_mug_on_the_flip_area_is_seen_upside_down(
    detector: DepthMugDetector, odd_places: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = odd_places
    found = {
        d.type: d
        for d in detector.detect(frame)
        if math.hypot(d.x_m - mugs[0].x_m, d.y_m - mugs[0].y_m) < 0.01
    }
    assert list(found) == ["big"]
    assert found["big"].upside_down


def test_mug_standing_in_the_tray_is_found(
    detector: DepthMugDetector, odd_places: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = odd_places
    score = score_frame(mugs, detector.detect(frame))
    assert (score.true_positives, score.false_positives, score.type_correct) == (3, 0, 3)


def test_handle_direction_follows_the_handle(
    detector: DepthMugDetector, odd_places: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = odd_places
    side = mugs[2]
    (d,) = [d for d in detector.detect(frame) if math.hypot(d.x_m - side.x_m, d.y_m - side.y_m) < 0.01]
    assert abs(math.remainder(d.handle_yaw_rad - side.yaw_rad, 2 * math.pi)) < math.radians(15)
    assert 0.5 < d.confidence <= 1.0


def test_a_slightly_tilted_extrinsic_is_corrected_by_the_table_fit(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = dataset_1
    tilt = math.radians(1.5)  # a calibration error about the camera's own x axis
    c, s = math.cos(tilt), math.sin(tilt)
    error = np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])
    tilted = replace(frame, world_from_camera=frame.world_from_camera @ error)
    score = score_frame(mugs, detector.detect(tilted))
    assert (score.true_positives, score.false_positives) == (12, 0)
    assert np.median(score.centre_errors_m) < 0.004


def test_depth_image_of_the_wrong_size_is_refused(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    _, frame = dataset_1
    small = replace(frame, depth_m=frame.depth_m[:240, :320])
    with pytest.raises(FrameError, match=r"^depth image is 320x240 pixels but the intrinsics say 640x480$"):
        detector.detect(small)


def test_camera_that_does_not_see_the_table_is_refused(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    _, frame = dataset_1
    lifted = frame.world_from_camera.copy()
    lifted[2, 3] += 0.5  # the extrinsic puts the camera half a metre too high
    with pytest.raises(
        FrameError, match=r"^no table plane in view near z = 0 .*check the camera's world_from_camera$"
    ):
        detector.detect(replace(frame, world_from_camera=lifted))


def test_blank_depth_image_is_refused(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    _, frame = dataset_1
    with pytest.raises(
        FrameError, match=r"^the depth image has only 0 valid pixels; is the camera covered\?$"
    ):
        detector.detect(replace(frame, depth_m=np.zeros_like(frame.depth_m)))


def test_an_empty_catalogue_is_refused() -> None:
    with pytest.raises(
        ValueError, match=r"^the mug catalogue is empty; configure at least one \[mug_types.<name>\]$"
    ):
        DepthMugDetector({})


def test_a_hidden_handle_is_reported_pointing_away_from_the_camera(
    detector: DepthMugDetector, layout: CellLayout
) -> None:
    x0, y0, x1, y1 = layout.counter_region_m
    yc = (y0 + y1) / 2
    # The camera looks along -y; a handle towards -y is behind its mug, one towards +y in plain view.
    hidden = SceneMug("hidden", SMALL_MUG, x1 - 0.15, yc, yaw_rad=-math.pi / 2)
    shown = SceneMug("shown", SMALL_MUG, x0 + 0.15, yc, yaw_rad=math.pi / 2)
    found = detector.detect(render(layout, [hidden, shown], noise=DepthNoise(), seed=3))
    by_id = {
        m.mug_id: d for m in (hidden, shown) for d in found if math.hypot(d.x_m - m.x_m, d.y_m - m.y_m) < 0.01
    }
    assert abs(math.remainder(by_id["hidden"].handle_yaw_rad - hidden.yaw_rad, 2 * math.pi)) < math.radians(
        35
    )
    assert by_id["hidden"].confidence < by_id["shown"].confidence


@pytest.mark.parametrize("gap_m", [0.010, 0.002])
def test_mugs_a_few_millimetres_apart_are_told_apart(
    detector: DepthMugDetector, layout: CellLayout, gap_m: float
) -> None:
    x0, y0, _, _ = layout.counter_region_m
    row = [
        SceneMug(
            f"r{i}", BIG_MUG if i % 2 else SMALL_MUG, x0 + 0.06 + i * (0.091 + gap_m), y0 + 0.05, -math.pi / 2
        )
        for i in range(4)
    ]
    # Along the line of sight as well: the nearer mug hides the lower part of the one behind it.
    column = [SceneMug("c0", BIG_MUG, 0.2, y0 + 0.05), SceneMug("c1", SMALL_MUG, 0.2, y0 + 0.141 + gap_m)]
    mugs = row + column
    score = score_frame(mugs, detector.detect(render(layout, mugs, noise=DepthNoise(), seed=1)))
    assert (score.true_positives, score.false_positives, score.type_correct) == (6, 0, 6)


def test_nan_and_infinite_depths_count_as_no_reading(
    detector: DepthMugDetector, dataset_1: tuple[list[SceneMug], RGBDFrame]
) -> None:
    mugs, frame = dataset_1
    depth = frame.depth_m.copy()
    depth[::7, ::5] = np.nan
    depth[3::11, 2::9] = np.inf
    score = score_frame(mugs, detector.detect(replace(frame, depth_m=depth)))
    assert (score.true_positives, score.false_positives) == (12, 0)


def test_centres_are_unbiased_on_a_noise_free_frame(detector: DepthMugDetector, layout: CellLayout) -> None:
    # The slanted view's brim bias and a tray tilting the table fit would each move centres by a millimetre.
    mugs = dataset_mugs(2, layout, MUG_TYPES, seed=3)
    found = detector.detect(render(layout, mugs))
    offsets = np.array(
        [min(((d.x_m - m.x_m, d.y_m - m.y_m) for d in found), key=lambda v: math.hypot(*v)) for m in mugs]
    )
    assert np.linalg.norm(offsets.mean(axis=0)) < 0.0007
    assert np.median(np.hypot(offsets[:, 0], offsets[:, 1])) < 0.0012
