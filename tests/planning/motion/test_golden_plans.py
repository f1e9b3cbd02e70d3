"""The planner's results on a fixed set of calls are the ones it gave before its stages became objects.

Each call's result (every step's phase, kind, opening, times and joint angles to 1e-6, the duration, energy
and handle yaw; or the refusal's words and blockers) is reduced to a digest. The expected digests were taken
from the planner as it was before the stages moved out of it (``_pick``, ``_flip``, ... as private methods);
a change here means the plans changed: find out why before taking the new digests.
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
    "upright": "dad1108dd0ca8bc8bee036937d8f4627056ad2b4c1172667ee8af58cbb8674f0",
    "upside down": "854fa8dbfa0fd394cef1248175c89b426bd0ef225817f03b5cf684d754a75aeb",
    "handle unseen": "579cd10af2d988e76d61c68b28abf78d256fa3cbcf059edae27e9418f986ad37",
    "crowded tray": "290536747e053bf1c965d5757361fe199ece58f831cd5c37b2c0b144b7c754be",
    "for slot, named mug blocked": "0f9dc876eeae3206ae4d7099e9c59c88d553625de5aacbada820c876c797f3e6",
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
