"""Command-line verbs import what they use when they run (STYLE.md rule 14): every help screen,
``config show``, ``statechart`` and the client verbs load none of the heavy libraries, so they start fast and
a plain install (no ``sim`` extra) runs them. Each case runs ``dishbot`` in a fresh interpreter and reads back
the modules it had loaded when the verb returned: a check of what was imported, not of how long it took."""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from cli.commands.arm import SIDE_GRASPS
from cli.main import VERBS, build_parser, named_verb
from daemon.config import load_config
from planning.arm import GraspKind
from tests.fakes.daemon import running_daemon
from tests.fakes.job import make_backend, make_world

HEAVY = frozenset({"mujoco", "scipy", "pinocchio", "cv2", "ortools", "numpy"})
ROBOT = "importtest"

# Runs cli.main.main on each argv of the JSON list argv[1], in order, and writes to the file argv[2] the
# exit code of each and the top-level packages it was the first to load (importing cli.main counts for the
# first argv).
_PROBE = """
import json, sys
loaded = {m.partition(".")[0] for m in sys.modules}
OURS = {"bench", "cli", "daemon", "description", "drivers", "perception", "planning", "recorder", "replay",
        "sim", "statechart", "wire"}
seen = set()
from cli.main import main
cases, out = json.loads(sys.argv[1]), sys.argv[2]
done = []
for argv in cases:
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    now = {m.partition(".")[0] for m in sys.modules}
    ours = {m for m in sys.modules if m.partition(".")[0] in OURS} - seen
    done.append({"argv": argv, "code": code, "new": sorted(now - loaded), "ours": sorted(ours)})
    loaded = now
    seen |= ours
with open(out, "w", encoding="utf-8") as f:
    json.dump(done, f)
"""


def run_cli(tmp_path: Path, *cases: Sequence[str]) -> list[dict[str, Any]]:
    """Run each argv in one fresh interpreter; per argv: exit code, the packages it loaded first (``new``)
    and the modules of dishbot it loaded first (``ours``)."""
    out = tmp_path / f"probe-{len(list(tmp_path.iterdir()))}.json"
    proc = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps([list(c) for c in cases]), str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    result: list[dict[str, Any]] = json.loads(out.read_text(encoding="utf-8"))
    return result


def heavy_loaded(results: list[dict[str, Any]]) -> dict[str, list[str]]:
    """Which verb loaded which heavy library first (empty: none did)."""
    return {
        " ".join(r["argv"]): sorted(HEAVY.intersection(r["new"]))
        for r in results
        if HEAVY.intersection(r["new"])
    }


def command_paths(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    """Every verb and sub-verb of the command line, found in the parser itself (new verbs are covered)."""
    yield path
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from command_paths(sub, (*path, name))


@pytest.mark.slow
def test_no_help_screen_loads_a_heavy_library(tmp_path: Path) -> None:
    paths = list(command_paths(build_parser()))
    assert ("bench", "sim") in paths
    assert ("config", "show") in paths
    results = run_cli(tmp_path, *[(*p, "--help") for p in paths])
    assert [r["code"] for r in results] == [0] * len(paths)
    assert heavy_loaded(results) == {}


def test_the_help_screen_loads_no_verb_and_reads_as_every_verb_registered() -> None:
    """``dishbot --help`` lists the verbs from ``cli.main.VERBS`` without importing their modules; the
    listing is what the modules themselves register."""
    assert build_parser(()).format_help() == build_parser().format_help()


@pytest.mark.slow
def test_the_bare_help_screen_imports_only_the_command_line_itself(tmp_path: Path) -> None:
    [result] = run_cli(tmp_path, ("--help",))
    assert result["code"] == 0
    assert set(result["ours"]) == {"cli", "cli.main", "cli.extras", "cli.logs"}
    assert not {"structlog", "logging", "asyncio", "zenoh", "msgspec", *HEAVY} & set(result["new"])


# What each verb that cannot log (``Verb.logs`` False) runs here: every one of them is covered.
QUIET_RUNS = {
    "plan": ("plan", "--dataset", "1"),
    "config": ("config", "show"),
    "statechart": ("statechart",),
}


def test_every_verb_that_cannot_log_is_checked_for_it() -> None:
    assert set(QUIET_RUNS) == {name for name, verb in VERBS.items() if not verb.logs}


@pytest.mark.parametrize("argv", QUIET_RUNS.values(), ids=" ".join)
@pytest.mark.slow
def test_a_verb_said_not_to_log_imports_no_structlog(tmp_path: Path, argv: tuple[str, ...]) -> None:
    """The command line configures structlog only for verbs that log; one that imported it could log to
    stdout unconfigured (and pay its import, a sixth of a plan's start)."""
    [result] = run_cli(tmp_path, argv)
    assert result["code"] == 0
    assert "structlog" not in result["new"]


@pytest.mark.slow
def test_a_plan_without_pictures_loads_no_picture_recorder_nor_zenoh_library(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``plan --dataset 1`` (the default method, auto) loads what it plans with: numpy and OR-Tools' CP-SAT
    helper (not ``cp_model``, which imports pandas at its top), not OpenCV, MCAP, Zenoh, structlog or the
    motion planner's libraries; a picture brings OpenCV, and of libraries only that. Once the rectangle
    optimum is kept (``planning.placement.cache``), the next plan does not load OR-Tools at all."""
    monkeypatch.setenv("DISHBOT_CACHE_DIR", str(tmp_path / "cache"))
    [result] = run_cli(tmp_path, ("plan", "--dataset", "1", "--json"))
    assert result["code"] == 0
    assert {"numpy", "ortools"} <= set(result["new"])
    [again] = run_cli(tmp_path, ("plan", "--dataset", "1", "--json"))
    assert again["code"] == 0
    assert "numpy" in again["new"]
    assert "ortools" not in again["new"]
    unused = {
        "cv2",
        "matplotlib",
        "zenoh",
        "mcap",
        "structlog",
        "asyncio",
        "scipy",
        "pinocchio",
        "mujoco",
        "pandas",
    }
    assert not unused & set(result["new"])
    layers = {m.partition(".")[0] for m in result["ours"]}
    assert not {"wire", "sim", "replay", "bench"} & layers
    # The config's [recording] section only (daemon.config declares it), not the MCAP writer or views; and
    # of perception the camera's frame limits ([camera] is that type) and the least-cost assignment (the
    # packer's, plain Python), not the detector.
    assert {m for m in result["ours"] if m.startswith("recorder")} <= {"recorder", "recorder.settings"}
    perception = {"perception", "perception.frames", "perception.assignment"}
    assert {m for m in result["ours"] if m.startswith("perception")} <= perception
    assert not {m for m in result["ours"] if m.startswith("planning.motion")}
    [drawn] = run_cli(
        tmp_path,
        ("plan", "--dataset", "1", "--svg", str(tmp_path / "p.svg"), "--png", str(tmp_path / "p.png")),
    )
    assert drawn["code"] == 0
    added = set(drawn["new"]) - set(result["new"])
    assert "cv2" in added
    # (and the standard library's modules pandas used to load before the picture: hashlib, hmac, ...)
    assert added - {"cv2"} <= sys.stdlib_module_names


@pytest.mark.parametrize(
    ("argv", "verb"),
    [
        (["status"], "status"),
        (["--log-level", "debug", "run", "--sim"], "run"),
        (["--log", "debug", "stop"], "stop"),
        (["--profile=robot.toml", "start", "--dataset", "2"], "start"),
        (["--profile", "status", "status"], "status"),
        (["--help"], None),
        ([], None),
    ],
)
def test_the_verb_is_the_first_word_that_is_no_option_nor_its_value(
    argv: list[str], verb: str | None
) -> None:
    assert named_verb(argv) == verb


@pytest.mark.slow
def test_a_verb_imports_its_own_module_and_no_other_verb(tmp_path: Path) -> None:
    [result] = run_cli(tmp_path, ("statechart",))
    assert result["code"] == 0
    verbs = {m for m in result["ours"] if m.startswith("cli.commands.") or m.startswith("bench")}
    assert verbs == {"cli.commands.statechart_cmd"}


@pytest.mark.parametrize(
    "argv", [("config", "show"), ("config", "show", "--json"), ("statechart",)], ids=" ".join
)
@pytest.mark.slow
def test_a_local_verb_loads_no_heavy_library(tmp_path: Path, argv: tuple[str, ...]) -> None:
    [result] = run_cli(tmp_path, argv)
    assert result["code"] == 0
    assert heavy_loaded([result]) == {}


@pytest.mark.slow
def test_the_client_verbs_load_no_heavy_library_while_they_command_a_daemon(tmp_path: Path) -> None:
    # From idle: pause, resume and stop are refused (exit 1), estop and reset accepted, start starts a job.
    verbs = {"status": 0, "pause": 1, "resume": 1, "stop": 1, "estop": 0, "reset": 0, "start": 0}
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})

    async def go() -> list[dict[str, Any]]:
        backend = make_backend(make_world(2))
        async with running_daemon(config, backend, tmp_path / "recordings") as d:
            base = ("--connect", d.endpoint, "--robot", ROBOT)
            results = []
            for verb in verbs:  # one interpreter each, in this order
                results += await asyncio.to_thread(run_cli, tmp_path, (verb, *base))
            results += await asyncio.to_thread(run_cli, tmp_path, ("monitor", *base, "--duration", "0.3"))
            return results

    results = asyncio.run(go())
    assert [r["code"] for r in results] == [*verbs.values(), 0]
    assert heavy_loaded(results) == {}
    # The client, the Zenoh session and the wire contract the monitor reads its samples with (whose state
    # names are the chart's leaves), not the daemon's other layers nor the other verbs.
    layers = {"planning", "perception", "statechart", "sim", "wire", "recorder", "replay", "bench"}
    loaded = {m for r in results for m in r["ours"]}
    contract = {"wire", "wire.messages", "statechart", "statechart.chart"}
    assert not {m for m in loaded if m.partition(".")[0] in layers} - contract
    assert {m for m in loaded if m.startswith("cli.commands.")} == {
        "cli.commands.client",
        "cli.commands.monitor",
    }


def test_the_arm_verbs_name_the_side_grasps_of_the_arm_model() -> None:
    """``arm ik --grasp`` spells the choices out so its parser needs no numpy; they must stay the model's."""
    assert tuple(k.value for k in GraspKind if k is not GraspKind.POSITION) == SIDE_GRASPS
