"""Scoring the detector on rendered scenes: dataset layouts on the counter, clutter, and detection matching.

The benchmark (``dishbot bench perception``) and the tests use these to render the thesis's datasets 1–3
(§5.3.3: 12 mugs on the counter) with the simulated depth camera and compare what the detector reports
with the scene's ground truth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from description.cell import CellLayout, SceneMug
from description.thesis import MugSpec
from perception.interfaces import Detection
from sim.counter import dataset_counter

# A detection farther than this from every mug is a false positive.
MATCH_GATE_M = 0.03


def dataset_mugs(
    number: int,
    cell: CellLayout,
    catalogue: Mapping[str, MugSpec],
    *,
    seed: int = 0,
    yaw_jitter_rad: float = math.radians(20),
    upside_down_fraction: float = 0.15,
) -> list[SceneMug]:
    """The mugs of dataset ``number`` where the simulated counter puts them (``sim.counter``), posed for
    scoring the detector.

    Handles point along +x as the planner assumes, give or take ``yaw_jitter_rad``, and a few mugs stand
    upside down, so a frame exercises more than one pose. Deterministic for a given seed.
    """
    rng = np.random.default_rng(seed * 1000 + number)
    return [
        replace(
            m,
            yaw_rad=float(rng.uniform(-yaw_jitter_rad, yaw_jitter_rad)),
            upside_down=bool(rng.random() < upside_down_fraction),
        )
        for m in dataset_counter(number, cell, catalogue).mugs
    ]


def clutter_xml(cell: CellLayout) -> str:
    """Things on the table that are not mugs: a ball and a box as tall as mugs, beside the flip area."""
    fx, fy = cell.flip_area_center_m
    r = cell.flip_area_radius_m
    return f"""    <body name="clutter/ball" pos="{fx - r - 0.07:.4f} {fy - 0.02:.4f} 0.042">
      <geom name="clutter/ball" type="sphere" size="0.042" rgba="0.9 0.8 0.1 1" mass="0.05"/>
    </body>
    <body name="clutter/box" pos="{fx + r + 0.06:.4f} {fy + 0.03:.4f} 0.05" euler="0 0 0.4">
      <geom name="clutter/box" type="box" size="0.045 0.045 0.05" rgba="0.6 0.6 0.6 1" mass="0.1"/>
    </body>
    <body name="clutter/carton" pos="{fx:.4f} {fy - r - 0.07:.4f} 0.04" euler="0 0 1.1">
      <geom name="clutter/carton" type="box" size="0.07 0.035 0.04" rgba="0.9 0.9 0.9 1" mass="0.1"/>
    </body>"""


@dataclass(frozen=True, slots=True)
class FrameScore:
    """How the detections of one frame compare with the truth."""

    true_positives: int
    false_positives: int
    false_negatives: int
    centre_errors_m: tuple[float, ...]
    type_correct: int
    upside_down_correct: int
    handle_errors_rad: tuple[float, ...]


def score_frame(truth: Sequence[SceneMug], detections: Sequence[Detection]) -> FrameScore:
    """Match detections to mugs (optimal assignment within ``MATCH_GATE_M``) and count what went right."""
    if not truth or not detections:
        return FrameScore(0, len(detections), len(truth), (), 0, 0, ())
    from scipy.optimize import linear_sum_assignment  # slow to import; only scoring needs it

    cost = np.array([[math.hypot(d.x_m - m.x_m, d.y_m - m.y_m) for d in detections] for m in truth])
    rows, cols = linear_sum_assignment(cost)
    pairs = [(r, c) for r, c in zip(rows, cols, strict=True) if cost[r, c] <= MATCH_GATE_M]
    errors = tuple(float(cost[r, c]) for r, c in pairs)
    type_ok = sum(truth[r].spec.name == detections[c].type for r, c in pairs)
    flip_ok = sum(truth[r].upside_down == detections[c].upside_down for r, c in pairs)
    handle = tuple(
        abs(math.remainder(detections[c].handle_yaw_rad - truth[r].yaw_rad, 2 * math.pi)) for r, c in pairs
    )
    tp = len(pairs)
    return FrameScore(tp, len(detections) - tp, len(truth) - tp, errors, type_ok, flip_ok, handle)
