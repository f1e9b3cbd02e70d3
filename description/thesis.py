"""Numbers taken from the reference thesis (Dagli, 2016), each with the section or table it comes from.

This is the only place those figures live; config defaults, datasets, the arm model and the benchmarks all
read them from here. Lengths are metres unless the name says ``_mm``; masses are kilograms.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final


@dataclass(frozen=True, slots=True)
class MugSpec:
    """One mug type of the catalogue (§5.3): brim diameter l, width with handle w."""

    name: str
    diameter_mm: int
    width_mm: int
    height_mm: int
    mass_kg: float


def mug_catalogue(mugs: Iterable[MugSpec]) -> dict[str, MugSpec]:
    """A mug catalogue as the planners, the detector and the simulated worlds take it: each type by name."""
    return {m.name: m for m in mugs}


# §5.3: the two mug types used in every placement test.
BIG_MUG: Final = MugSpec("big", diameter_mm=91, width_mm=120, height_mm=106, mass_kg=0.2)
SMALL_MUG: Final = MugSpec("small", diameter_mm=74, width_mm=100, height_mm=80, mass_kg=0.1)
MUG_TYPES: Final[dict[str, MugSpec]] = mug_catalogue((BIG_MUG, SMALL_MUG))

# §5.3.1, Table 5.19: the tolerance between footprints that gave no collisions.
TOLERANCE_MM: Final = 10

# §4.3, Eq 4.40-4.45: the tray the arm can serve; §5.3: the full-size dishwasher tray.
ROBOT_TRAY_MM: Final = (332, 374)
FULL_TRAY_MM: Final = (475, 520)


@dataclass(frozen=True, slots=True)
class Dataset:
    """A placement test set of §5.3: how many big and small mugs, and on which tray."""

    number: int
    big: int
    small: int
    tray_mm: tuple[int, int]
    # §5.3.2 (Tables 5.20-5.25), §5.2.3: best mugs placed by the thesis's methods; by people (mean).
    thesis_best_placed: int
    human_placed: float


DATASETS: Final[dict[int, Dataset]] = {
    1: Dataset(1, 6, 6, ROBOT_TRAY_MM, thesis_best_placed=10, human_placed=12),
    2: Dataset(2, 8, 4, ROBOT_TRAY_MM, thesis_best_placed=8, human_placed=12),
    3: Dataset(3, 4, 8, ROBOT_TRAY_MM, thesis_best_placed=10, human_placed=12),
    4: Dataset(4, 20, 10, FULL_TRAY_MM, thesis_best_placed=17, human_placed=28.4),
    5: Dataset(5, 15, 15, FULL_TRAY_MM, thesis_best_placed=18, human_placed=29.95),
    6: Dataset(6, 10, 20, FULL_TRAY_MM, thesis_best_placed=20, human_placed=30),
}


@dataclass(frozen=True, slots=True)
class DHRow:
    """One row of Table 3.1, read in the modified (Craig) convention: Rx(alpha)·Tx(a)·Rz(theta)·Tz(d)."""

    joint: str
    a_m: float
    d_m: float
    alpha_rad: float


# §3.2.1, Table 3.1.
DH_TABLE: Final[tuple[DHRow, ...]] = (
    DHRow("shoulder_turn", -0.000075, 0.01, 0.0),
    DHRow("shoulder_lift", -0.000465, -0.00000009, -math.pi / 2),
    DHRow("elbow_lift", 0.294, 0.00000009, 0.0),
    DHRow("wrist_lift", 0.2838, -0.00000003, 0.0),
    DHRow("wrist_turn", -0.00003, 0.074, -math.pi / 2),
    DHRow("gripper", -0.00001, 0.019, 0.0),
)

# §3.2.1: the servo driving each joint, in chain order; default bus ids 1-6 follow this order.
JOINT_SERVOS: Final[tuple[tuple[str, str], ...]] = (
    ("shoulder_turn", "MX-64T"),
    ("shoulder_lift", "MX-106T"),
    ("elbow_lift", "MX-64T"),
    ("wrist_lift", "MX-28T"),
    ("wrist_turn", "AX-12A"),
    ("gripper", "AX-12A"),
)

# §3.2.1: rated payload 0.2 kg at 0.728 m from the shoulder.
ARM_PAYLOAD_KG: Final = 0.2

# §3.2.1: the FSR is read through a 10 kOhm pull-down divider from the Arduino's 5 V pin.
FSR_PULLDOWN_OHM: Final = 10_000.0
FSR_SUPPLY_V: Final = 5.0

# §3.2.3 / §5.3.2: the depth camera's pose in the simulated cell.
CAMERA_HEIGHT_M: Final = 1.70
CAMERA_DISTANCE_TO_TABLE_M: Final = 0.70
CAMERA_PITCH_RAD: Final = math.radians(55.0)

# §4.1, §4.3.1: a mug detected within this distance of its previous position is the same ("known") mug.
KNOWN_MUG_TOLERANCE_M: Final = 0.01

# §4.3: gripper heights above the table for each phase.
GRASP_HEIGHT_M: Final = 0.06
CARRY_CLEARANCE_M: Final = 0.07  # above the tallest mug
PLACE_HEIGHT_M: Final = 0.06

# §3.1.1.2: at most 3 minutes per mug; §5.3.3, Table 5.26: the Gazebo runs took about 55 s per mug.
MAX_SECONDS_PER_MUG: Final = 180.0
THESIS_GAZEBO_SECONDS_PER_MUG: Final = 55.0

GRAVITY_M_S2: Final = 9.81

# §3.2.1: the arm runs from a 12 V DC supply (the MX servos' recommended voltage, the AX-12A's maximum).
SUPPLY_VOLTAGE_V: Final = 12.0
# §3.2.1: the rated payload (ARM_PAYLOAD_KG) is held this far from the shoulder.
ARM_PAYLOAD_REACH_M: Final = 0.728
# §3.1.1.1: the gripper must open at least 10 cm to take a mug.
GRIPPER_MIN_OPENING_M: Final = 0.10
# §4.3: a carried mug passes at least 3 cm above the mugs below it.
TRANSIT_CLEARANCE_M: Final = 0.03
# §4.3, Eq 4.43: the tray's lower y limit was fixed at 13.2 cm.
TRAY_Y_LOWER_M: Final = 0.132
# §4.3: the side-grasp workspace the thesis found in Gazebo: 22 cm along x, 82 cm along y.
THESIS_SIDE_GRASP_RANGE_M: Final = (0.22, 0.82)
# Appendix A: worst position error of the 6-DOF solver on the 5-DOF arm, before and after the fitted fix.
THESIS_IK_ERROR_BEFORE_M: Final = 0.177
THESIS_IK_ERROR_AFTER_M: Final = 0.032
# Appendix A, Eq A.1-A.3: the averaged quadratic error models in (x, |y|), coefficients of
# (1, x, |y|, x², x|y|, y²); the reached x, |y| and the z offset for a commanded (x, y).
THESIS_ERROR_FIT_X: Final = (0.034652, 0.84905, 0.3283, 0.146775, -0.437175, 0.1592)
THESIS_ERROR_FIT_Y: Final = (-0.037373, 0.0927725, 0.5603, -0.04269, 0.1567, 0.450425)
THESIS_ERROR_FIT_Z: Final = (0.0, 0.007373, -0.001207, -0.03678, 0.002317, -0.040748)

# --- Placement planning (§4.2, §5.2, §5.3) ---

# §5.2.2, Table 5.2: answers of the 258-person survey ranking each parameter 1st..4th, or "not important".
SURVEY_RANK_COUNTS: Final[dict[str, tuple[int, int, int, int]]] = {
    "n": (133, 66, 36, 17),
    "E": (43, 96, 66, 32),
    "t": (52, 58, 101, 27),
    "s": (26, 37, 36, 82),
}
SURVEY_NOT_IMPORTANT: Final[dict[str, int]] = {"n": 6, "E": 21, "t": 20, "s": 77}
# §5.2.2, Table 5.3: the overall weights Eq 4.7 gives from Table 5.2.
SURVEY_OVERALL_WEIGHTS: Final[dict[str, float]] = {"n": 0.338, "t": 0.252, "E": 0.258, "s": 0.152}

# §5.2.5, Eq 5.2 (user preference-based cost) and Eq 5.3 (engineering cost): weighted-sum weights.
UPC_WEIGHTS: Final[dict[str, float]] = {"n": 0.37, "E": 0.28, "t": 0.27, "s": 0.08}
EC_WEIGHTS: Final[dict[str, float]] = {"n": 0.43, "E": 0.30, "t": 0.27, "s": 0.0}
# §5.2.6, Eq 5.5: the ranking-fitness order (the covered area A breaks ties in n).
RF_RANKING: Final[tuple[str, ...]] = ("n", "A", "E", "t", "s")


@dataclass(frozen=True, slots=True)
class SAParams:
    """§5.3: simulated annealing."""

    t_max: float = 1000.0
    cooling_rate: float = 0.99
    t_abs: float = 0.01


@dataclass(frozen=True, slots=True)
class GAParams:
    """§5.3 (from Gehring and Bortfeldt): genetic algorithm."""

    npop: int = 50
    ngen: int = 30
    nrep: int = 10
    pc: float = 0.67
    pm: float = 0.33


@dataclass(frozen=True, slots=True)
class PSOParams:
    """§5.3: both particle swarm variants (ω falls linearly from w_max to w_min, Eq 4.20)."""

    tau_max: int = 500
    w_max: float = 0.9
    w_min: float = 0.4
    c1: float = 1.5
    c2: float = 1.5
    c3: float = 5.0
    ps: float = 0.5


SA_PARAMS: Final = SAParams()
GA_PARAMS: Final = GAParams()
PSO_PARAMS: Final = PSOParams()

# §5.3.2, Table 5.21 (lowest bin-packing cost, ranking fitness): run time of each method's best combination,
# in minutes, per dataset (C++, Intel i7-2600).
THESIS_RUN_MINUTES: Final[dict[str, tuple[float, ...]]] = {
    "sa": (0.1466, 0.1351, 0.2532, 0.6532, 0.6666, 0.5162),
    "ga": (0.1926, 0.1644, 0.1815, 0.7174, 0.7239, 0.6635),
    "psop-n": (0.5184, 0.6004, 0.5997, 1.0383, 1.0836, 1.2837),
    "psop-i": (0.6699, 0.6490, 0.6850, 1.0621, 1.0841, 1.2448),
    "psok-n": (0.2307, 0.2266, 0.2442, 0.8788, 0.9176, 0.6146),
    "psok-i": (0.2309, 0.2301, 0.2349, 0.6919, 0.7330, 0.6221),
    "bh": (0.0001, 0.0001, 0.0001, 0.0003, 0.0002, 0.0003),
}
# --- end of placement planning ---
