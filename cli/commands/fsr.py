"""``dishbot fsr calibrate``: measure the gripper pad's FSR at rest and under a known weight.

It prints the gain that makes the sensor read the weight in newtons and grasp thresholds above the noise,
as TOML to paste into the ``[hardware.fsr]`` table of the config.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
from collections.abc import Callable
from typing import TYPE_CHECKING

from daemon.errors import UsageError
from description.thesis import GRAVITY_M_S2
from drivers.errors import SensorFault

if TYPE_CHECKING:
    from drivers.fsr import FsrReader
    from drivers.interfaces import Clock


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("fsr", help="the force-sensing resistor in the gripper pad")
    fsr_sub = parser.add_subparsers(dest="fsr_command", metavar="ACTION", required=True)
    cal = fsr_sub.add_parser(
        "calibrate",
        help="sample the pad empty and with a known weight; print the gain and thresholds for the config",
    )
    cal.add_argument(
        "--port",
        default="/dev/dishbot-fsr",
        help="serial device of the FSR Arduino (default /dev/dishbot-fsr, from drivers/udev/)",
    )
    cal.add_argument("--mass-kg", type=float, required=True, help="the calibration weight on the pad, kg")
    cal.add_argument("--seconds", type=float, default=2.0, help="how long to sample each phase (default 2)")
    cal.add_argument("--json", action="store_true", help="print JSON instead of TOML")
    cal.set_defaults(handler=_calibrate)


def _calibrate(args: argparse.Namespace) -> int:
    if not 0 < args.mass_kg <= 5:
        raise UsageError(f"--mass-kg {args.mass_kg} must be in (0, 5] kg")
    if not 0.2 <= args.seconds <= 60:
        raise UsageError(f"--seconds {args.seconds} must be in [0.2, 60]")
    from daemon.clock import RealClock

    try:
        clock = RealClock()
        result = clock.run(calibrate(args.port, args.mass_kg, args.seconds, prompt=input, clock=clock))
    except SensorFault as e:
        raise UsageError(str(e)) from e
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print("[hardware.fsr]")
        for key in ("gain", "threshold_n", "release_n"):
            print(f"{key} = {result[key]:.4g}")
    return 0


async def calibrate(
    port: str, mass_kg: float, seconds: float, *, prompt: Callable[[str], str], clock: Clock
) -> dict[str, float]:
    """Sample at rest and loaded; the gain maps the loaded reading to m·g, thresholds sit between."""
    from drivers.fsr import FsrReader

    async with FsrReader(port, clock=clock, threshold_n=1e9, release_n=0.0) as reader:
        await asyncio.to_thread(prompt, "Take everything off the gripper pad, then press Enter: ")
        rest = await _sample(reader, seconds)
        await asyncio.to_thread(prompt, f"Put the {mass_kg} kg weight on the pad, then press Enter: ")
        loaded = await _sample(reader, seconds)
    # Medians: the first samples after Enter may still show the hand putting the weight down.
    rest_mean, rest_sd = statistics.median(rest), statistics.pstdev(rest)
    load_mean = statistics.median(loaded)
    if load_mean <= rest_mean + 3 * rest_sd or load_mean <= 0:
        raise SensorFault(
            f"the pad read {load_mean:.3f} N loaded and {rest_mean:.3f} ± {rest_sd:.3f} N empty: the weight "
            "did not register; check the FSR wiring and that the weight sits on the sensing area"
        )
    gain = mass_kg * GRAVITY_M_S2 / load_mean
    noise_n = (rest_mean + 6 * rest_sd) * gain
    threshold = max(noise_n * 2, 0.5 * mass_kg * GRAVITY_M_S2)
    return {
        "gain": gain,
        "threshold_n": threshold,
        "release_n": max(noise_n, 0.5 * threshold),
        "rest_n": rest_mean * gain,
        "rest_sd_n": rest_sd * gain,
        "loaded_n": load_mean * gain,
    }


async def _sample(reader: FsrReader, seconds: float) -> list[float]:
    """Every new reading's unscaled force for ``seconds``; SensorFault when the stream is dead."""
    values: list[float] = []
    last_seq = -1
    clock = reader.clock
    end = clock.monotonic() + seconds
    while clock.monotonic() < end:
        reading = reader.latest()
        if reading is not None and reading.seq != last_seq:
            last_seq = reading.seq
            values.append(reading.force_n)
        await clock.sleep(0.005)
    if len(values) < 5:
        raise SensorFault(f"the FSR on {reader.port} sent only {len(values)} samples in {seconds} s")
    return values
