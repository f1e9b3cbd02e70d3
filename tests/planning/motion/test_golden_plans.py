"""The planner's results on a fixed set of calls are the ones it gave before its stages became objects.

Each call's result (every step's phase, kind, opening, times and joint angles to 1e-6, the duration, energy
and handle yaw; or the refusal's words and blockers) is reduced to a digest. The expected digests were taken
from the planner as it was before the stages moved out of it (``_pick``, ``_flip``, ... as private methods);
a change here means the plans changed: find out why before taking the new digests. Taken again when the
set-downs (``flip.set_down``, ``place.descend``) got their slow last stretch: the cycles' last 3 cm down are
slower, and the crowded tray's refusal, the same words at the same place, counts the descent's poses anew.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import replace

import pytest

from daemon.config import load_config
from description.thesis import MUG_TYPES
from planning.arm import ArmModel
from planning.interfaces import CyclePlan, MotionRefused, MugPose, TraySlot
from planning.motion import CyclePlanner

START_Q = (0.0, -1.2, 1.7, -2.0, -math.pi / 2)
MUG = MugPose("m1", "big", -0.10, 0.45, handle_yaw_rad=math.atan2(0.45, -0.10))
NEIGHBOURS = [MugPose("m2", "small", 0.08, 0.45), MugPose("m3", "big", -0.10, 0.58)]
SLOT = TraySlot("m1", "big", 0.45, 0.05)
PLACED = [TraySlot("m4", "small", 0.45, -0.06), TraySlot("m5", "big", 0.60, 0.05)]
# Mugs packed round the slot, a handle towards it: the cycle is refused, and its words are the result.
CROWDED = [
    TraySlot("m6", "big", 0.45, 0.14, handle_yaw_rad=-math.pi / 2),
    TraySlot("m7", "small", 0.36, 0.05, handle_yaw_rad=0.0),
    TraySlot("m8", "small", 0.45, -0.04),
]

EXPECTED = {
    "upright": "feab2f10e1c42835aff92dbf56471c8e137cee33bb99360e977a8b021ed586d2",
    "upside down": "3146b46d5cf9593322a018be03cfe383695348af889c25372743431754d14345",
    "handle unseen": "f76318ce93bf447167bb5aa06ba6bf17f348f6de7d7bc1043027508a7168224d",
    "crowded tray": "bef2dc4d6fb32893c7c4c55269b692339a86bc31bfa2bb62c2ff5b989b8b95e5",
    "for slot, named mug blocked": "da958e0f0e97c0817505190c1adc6a574295c0e8b43b5ae7e37b3d785615f8bf",
    "move home": "12d9c97823d0cb56f63b3420d4c54d1e89272f8b07f230a5c7d06fbdff893e93",
}


def _numbers(values: object) -> str:
    return ",".join(f"{float(v):.6f}" for v in values)  # type: ignore[attr-defined]


def _digest(result: object) -> str:
    h = hashlib.sha256()
    if isinstance(result, MotionRefused):
        h.update(f"refused|{result}|{sorted(result.blockers)}".encode())
        return h.hexdigest()
    if isinstance(result, tuple):
        mug, result = result
        h.update(f"mug|{mug}".encode())
    if isinstance(result, CyclePlan):
        for s in result.steps:
            h.update(f"step|{s.phase}|{s.kind}|{s.aperture_m}".encode())
            if s.trajectory is not None:
                h.update(_numbers(s.trajectory.times).encode())
                h.update(_numbers(s.trajectory.positions.reshape(-1)).encode())
        yaw = None if result.handle_yaw_rad is None else round(result.handle_yaw_rad, 6)
        h.update(f"{result.duration_s:.6f}|{result.energy_j:.6f}|{yaw}".encode())
        return h.hexdigest()
    h.update(_numbers(result.times).encode())  # type: ignore[attr-defined]
    h.update(_numbers(result.positions.reshape(-1)).encode())  # type: ignore[attr-defined]
    return h.hexdigest()


def digests() -> dict[str, str]:
    """Each fixed call's digest (also run by hand on the planner before the change, to take EXPECTED)."""
    planner = CyclePlanner(ArmModel.load(), load_config().cell, MUG_TYPES)
    calls: dict[str, Callable[[], object]] = {
        "upright": lambda: planner.plan_cycle(START_Q, MUG, SLOT, PLACED, counter=NEIGHBOURS),
        "upside down": lambda: planner.plan_cycle(
            START_Q, replace(MUG, upside_down=True), SLOT, PLACED, counter=NEIGHBOURS
        ),
        "handle unseen": lambda: planner.plan_cycle(
            START_Q, replace(MUG, handle_seen=False), SLOT, [], counter=NEIGHBOURS
        ),
        "crowded tray": lambda: planner.plan_cycle(START_Q, MUG, SLOT, CROWDED, counter=NEIGHBOURS),
        # m3 stands behind m1: m1 takes its slot.
        "for slot, named mug blocked": lambda: planner.plan_for_slot(
            START_Q, replace(SLOT, mug_id="m3"), [MUG, *NEIGHBOURS], PLACED
        ),
        "move home": lambda: planner.plan_move(
            (0.3, -1.0, 1.5, -1.8, -1.2), START_Q, label="home", counter=NEIGHBOURS, on_tray=PLACED
        ),
    }
    out = {}
    for name, call in calls.items():
        try:
            result = call()
        except MotionRefused as e:
            result = e
        out[name] = _digest(result)
    return out


@pytest.fixture(scope="module")
def now() -> dict[str, str]:
    return digests()


@pytest.mark.parametrize("call", list(EXPECTED))
def test_the_plan_of_a_fixed_call_is_unchanged(now: dict[str, str], call: str) -> None:
    assert now[call] == EXPECTED[call]
