"""Faults compose: several faults on one device at once act together, and each one's end takes away only
its own effect. Every overlap pair of faults on one device (the same kind twice, and two different kinds),
on both cells, with the device's real condition read while both act, after the short one ended (the long
one must still act) and after the long one ended (nothing may be left)."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from daemon.app import ServeContext
from daemon.sim_backend import KinematicCounter, MujocoCounter
from drivers.sim.camera import FaultyCamera
from drivers.sim.fsr import FsrSimulator
from drivers.sim.servo_chain import ServoChainSimulator
from replay.faults import CAMERA_KINDS, FaultSpec, slot_of
from tests.replay.faulty import run_with_faults

SERVO = 2
WINDOW_S = 1.4  # each pair has its own window of simulated time: the long fault at +0.1 for 1.0 s, the
LONG_AT, LONG_S = 0.1, 1.0  # short one at +0.3 for 0.3 s
SHORT_AT, SHORT_S = 0.3, 0.3
PROBES = {"both": 0.45, "long": 0.8, "none": 1.3}  # when the device is read, in each window

# Every kind that lasts, by the device it acts on.
DEVICES: dict[str, tuple[str, ...]] = {
    "servo": ("servo_overload", "servo_overheat", "servo_voltage", "servo_silent"),
    "bus": ("bus_unplug", "bus_corrupt"),
    "fsr": ("fsr_drop", "fsr_silent", "bus_unplug:fsr"),
    "camera": tuple(CAMERA_KINDS),
}


def pairs() -> list[tuple[str, str]]:
    """(long, short): every kind with itself, and every ordered pair of different kinds on one device."""
    kinds = sorted({k for ks in DEVICES.values() for k in ks})
    same = [(k, k) for k in kinds]
    different = [p for ks in DEVICES.values() for p in itertools.permutations(ks, 2)]
    return same + different


def spec(index: int, name: str, at_s: float, duration_s: float) -> FaultSpec:
    kind, _, device = name.partition(":")
    extra: dict[str, object] = {}
    if kind.startswith("servo_"):
        extra["servo"] = SERVO
    if kind == "bus_corrupt":
        extra.update(rate=0.05, seed=index)
    if kind == "bus_unplug":
        extra["device"] = device or "servo"
    return FaultSpec(index=index, kind=kind, at_s=at_s, duration_s=duration_s, **extra)  # type: ignore[arg-type]


@dataclass
class Probe:
    """Reads one device condition (a fault's slot) from the cell's devices: truthy while a fault holds it."""

    read: Callable[[tuple[str, ...]], object]


def kinematic_probe(ctx: ServeContext) -> Probe:
    counter = ctx.backend.counter
    assert isinstance(counter, KinematicCounter)
    return simulators_probe(counter.cell.servo_sim, counter.cell.fsr_sim, counter.camera)


def mujoco_probe(ctx: ServeContext) -> Probe:
    counter = ctx.backend.counter
    assert isinstance(counter, MujocoCounter)
    assert counter.camera is not None
    return simulators_probe(counter.cell.servo_sim, counter.cell.fsr_sim, counter.camera)


def simulators_probe(servos: ServoChainSimulator, fsr: FsrSimulator, camera: FaultyCamera) -> Probe:
    """Both cells' devices are the same simulators: read their conditions the same way."""

    def read(slot: tuple[str, ...]) -> object:
        kind = slot[0]
        if kind == "camera":
            return camera.fault
        if kind.startswith("servo_"):
            servo = servos.servo(int(slot[1]))
            if kind == "servo_overload":
                return "overload" in servo.conditions
            if kind == "servo_overheat":
                return servo.get("present_temperature") > servo.get("temperature_limit")
            if kind == "servo_voltage":
                return servo.get("present_voltage") < servo.get("min_voltage")
            return servo.silent
        # The simulators keep these conditions to themselves (no register shows them): read them directly.
        if kind == "bus_unplug":
            link = (fsr if slot[1] == "fsr" else servos)._link
            assert link is not None
            return not link.plugged
        if kind == "bus_corrupt":
            return servos._corrupt_rate
        return {"fsr_drop": fsr._dropped, "fsr_silent": fsr._silent}[kind]

    return Probe(read)


@pytest.mark.slow
@pytest.mark.timeout(900)  # a cap for a loaded machine (90 daemon-seconds of physics), not a speed claim
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
def test_every_overlap_pair_on_one_device_composes(tmp_path: Path, world: str) -> None:
    plan = pairs()
    faults: list[FaultSpec] = []
    for i, (long, short) in enumerate(plan):
        start = 1.0 + i * WINDOW_S
        faults.append(spec(2 * i + 1, long, start + LONG_AT, LONG_S))
        faults.append(spec(2 * i + 2, short, start + SHORT_AT, SHORT_S))
    seen: dict[tuple[int, str], tuple[object, object]] = {}

    def probe_all(ctx: ServeContext) -> None:
        probe = (kinematic_probe if world == "kinematic" else mujoco_probe)(ctx)
        t0 = ctx.clock.monotonic()

        async def read_at(i: int, when: str, t: float) -> None:
            await ctx.clock.sleep_until(t)
            long, short = faults[2 * i], faults[2 * i + 1]
            long_slot, short_slot = slot_of(long), slot_of(short)
            assert long_slot is not None
            assert short_slot is not None
            seen[(i, when)] = (probe.read(long_slot), probe.read(short_slot))

        for i in range(len(plan)):
            for when, offset in PROBES.items():
                t = t0 + 1.0 + i * WINDOW_S + offset
                asyncio.get_running_loop().create_task(read_at(i, when, t))

    run = run_with_faults(
        tmp_path,
        tuple(faults),
        world=world,
        once=False,
        stop_after_s=2.0 + len(plan) * WINDOW_S,
        on_ready=probe_all,
    )
    assert [o.index for o in run.injector.outcomes() if not o.fired] == []
    wrong = []
    for i, (long, short) in enumerate(plan):
        both, after_short, after_long = seen[(i, "both")], seen[(i, "long")], seen[(i, "none")]
        long_spec = faults[2 * i]
        if long.startswith("camera_"):
            order = ("camera_hang", "camera_no_frame", "camera_bad_frame", "camera_stale")
            winner = min((long, short), key=order.index)
            expected = (CAMERA_KINDS[winner], CAMERA_KINDS[winner]) if short.startswith("camera_") else None
            if both != expected:
                wrong.append(f"{long}+{short} both on: camera {both}, expected {expected}")
            if after_short[0] != CAMERA_KINDS[long]:
                wrong.append(f"{long}+{short} after the short one: camera {after_short[0]}")
        else:
            if not (both[0] and both[1]):
                wrong.append(f"{long}+{short} both on: {both}")
            if not after_short[0]:
                wrong.append(
                    f"{long}+{short}: the short one's end took the long one's effect ({after_short})"
                )
            if slot_of(long_spec) != slot_of(faults[2 * i + 1]) and after_short[1]:
                wrong.append(f"{long}+{short}: the short one's effect outlived it ({after_short})")
        if after_long[0] or after_long[1]:
            wrong.append(f"{long}+{short}: something left after both ended ({after_long})")
        ended = {int(str(r["index"])): r.get("ended_at_s") for r in run.injector.fired if "ended_at_s" in r}
        for f in (faults[2 * i], faults[2 * i + 1]):
            assert f.at_s is not None
            assert f.duration_s is not None
            if ended.get(f.index) != pytest.approx(f.at_s + f.duration_s, abs=0.02):
                wrong.append(f"{long}+{short}: fault {f.index} ended at {ended.get(f.index)}")
    assert wrong == [], f"{len(wrong)} of {len(plan)} pairs: " + "; ".join(wrong)


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
def test_a_short_stale_spell_inside_long_bad_frames_ends_as_the_bad_frames_require(
    tmp_path: Path, world: str
) -> None:
    text = (
        '[[fault]]\nkind = "camera_bad_frame"\nat_state = "detect"\nduration_s = 100\n\n'
        '[[fault]]\nkind = "camera_stale"\nat_state = "detect"\nduration_s = 1\n'
    )
    run = run_with_faults(tmp_path, text, world=world, mugs=1)
    assert run.result.end_state == "fault"
    # One device path (issue 21, item 3): both cells' frame checks refuse the bad frame alike.
    assert run.event("fault")["reason"] == "camera: bad frame (NaN depth)"
    assert [(o.index, o.fired) for o in run.injector.outcomes()] == [(1, True), (2, True)]


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
def test_a_short_unplug_inside_a_long_one_leaves_the_bus_gone_until_the_long_one_ends(
    tmp_path: Path, world: str
) -> None:
    text = (
        '[[fault]]\nkind = "bus_unplug"\nat_s = 2\nduration_s = 20\n\n'
        '[[fault]]\nkind = "bus_unplug"\nat_s = 3\nduration_s = 1\n'
    )
    run = run_with_faults(tmp_path, text, world=world, once=False, stop_after_s=40)
    assert [(r["index"], r["fired_at_s"], r["ended_at_s"]) for r in run.injector.fired] == [
        (1, 2.0, 22.0),
        (2, 3.0, 4.0),
    ]
    pulled = float(str(run.events("fault_injected")[0]["t"]))
    bus = [
        (e["kind"], float(str(e["t"])) - pulled)
        for e in run.events()
        if e["kind"] in ("bus_lost", "bus_restored")
    ]
    assert bus, "the daemon never met the pulled adapter"
    assert bus[0][0] == "bus_lost"
    assert all(t >= 20.0 - 1e-6 for kind, t in bus if kind == "bus_restored"), bus
