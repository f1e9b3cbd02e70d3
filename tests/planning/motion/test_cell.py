"""The cell layout: validation of the [cell] values and the start-up reachability check."""

from __future__ import annotations

import tomllib

import pytest

from daemon import commands
from planning.arm import ArmModel
from planning.motion import CellLayout, InvalidCell, carry_height_m

DEFAULT_CONFIG = commands.__path__[0].rsplit("/", 1)[0] + "/default_config.toml"


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load()


def _default_cell() -> CellLayout:
    with open(DEFAULT_CONFIG, "rb") as f:
        return CellLayout.from_mapping(tomllib.load(f)["cell"])


def test_default_cell_is_reachable_everywhere(arm: ArmModel) -> None:
    assert _default_cell().check_reachable(arm) == []


def test_a_tray_next_to_the_base_is_refused_with_its_near_points(arm: ArmModel) -> None:
    cell = CellLayout((-0.45, 0.37, 0.45, 0.575), (0.30, -0.40), 0.08, (0.10, -0.187), (332, 374))
    problems = cell.check_reachable(arm)
    assert problems
    assert all(p.startswith("tray point (0.1") for p in problems)
    assert "side-upside-down grasp at z=0.060 m: no solution within the joint limits" in problems[0]


def test_a_counter_region_beyond_reach_names_the_far_corners(arm: ArmModel) -> None:
    cell = CellLayout((-0.30, 0.40, 0.25, 0.90), (0.30, -0.40), 0.08, (0.34, -0.187), (332, 374))
    problems = cell.check_reachable(arm)
    # Mug axes stay a small mug's brim radius (37 mm) inside the region.
    assert [p.split(" m,")[0] for p in problems] == [
        "counter point (0.213, 0.863)",
        "counter point (-0.263, 0.863)",
    ]
    assert "out of reach for a side grasp: the wrist would be" in problems[0]


def test_a_counter_region_reaching_in_to_the_base_names_its_nearest_point(arm: ArmModel) -> None:
    cell = CellLayout((-0.30, 0.25, 0.25, 0.55), (0.30, -0.40), 0.08, (0.34, -0.187), (332, 374))
    problems = cell.check_reachable(arm)
    assert [p.split(" m,")[0] for p in problems] == [
        "counter point (0.213, 0.287)",
        "counter point (0.000, 0.287)",
    ]


def test_inverted_counter_region_is_refused() -> None:
    with pytest.raises(InvalidCell, match=r"^cell.counter_region_m: \[0.3, 0.3, 0.25, 0.62\] is not \[x_min"):
        CellLayout((0.30, 0.30, 0.25, 0.62), (0.30, -0.40), 0.08, (0.34, -0.187), (332, 374))


def test_missing_cell_key_is_named() -> None:
    with pytest.raises(InvalidCell, match=r"^cell.tray_origin_m is missing$"):
        CellLayout.from_mapping(
            {"counter_region_m": [0, 0, 1, 1], "flip_area_center_m": [0, 0], "flip_area_radius_m": 0.1}
        )


def test_zero_flip_radius_is_refused() -> None:
    with pytest.raises(InvalidCell, match=r"^cell.flip_area_radius_m: 0.0 must be > 0$"):
        CellLayout((-0.30, 0.30, 0.25, 0.62), (0.30, -0.40), 0.0, (0.34, -0.187), (332, 374))


def test_carry_height_keeps_three_centimetres_under_the_held_mug() -> None:
    # 106 mm mug: the thesis's 7 cm above it would leave the held mug's bottom 1 cm above; raise to 3 cm
    # (plus a 5 mm margin for the IK residual).
    assert carry_height_m(0.106) == pytest.approx(0.106 + 0.03 + 0.06 + 0.005)
