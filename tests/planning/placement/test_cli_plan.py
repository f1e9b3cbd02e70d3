"""``dishbot plan``: output formats, pictures written whole, and one exact line for each kind of bad input."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main
from daemon.config import load_config
from planning.placement import PlanOptions, plan
from planning.placement.datasets import cell_dataset_problem
from planning.placement.heuristics import Heuristic
from planning.placement.sorts import Sort
from tests.planning.placement.test_problem import EXAMPLE


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["plan", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_dataset_plan_prints_json_with_the_proven_optimum(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "--dataset", "2", "--footprint", "rect", "--json")
    assert code == 0
    doc = json.loads(out)
    assert (doc["n"], doc["optimal"], doc["upper_bound"], doc["method"]) == (8, True, 8, "auto")
    assert [p["order"] for p in doc["placed"]] == list(range(1, 9))


def test_problem_file_with_the_documented_format_plans_around_the_mug_on_the_tray(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    problem = tmp_path / "problem.json"
    problem.write_text(json.dumps(EXAMPLE))
    code, out, _ = run(capsys, str(problem), "--method", "bh", "--json")
    assert code == 0
    placed = json.loads(out)["placed"]
    assert [p["id"] for p in placed] == ["m1"]


def test_summary_names_what_is_left_on_the_counter(capsys: pytest.CaptureFixture[str]) -> None:
    rect = ("--dataset", "1", "--footprint", "rect")
    code, out, _ = run(capsys, *rect, "--method", "bh", "--heuristic", "tlf", "--sort", "cif")
    assert code == 0
    expected = plan(
        cell_dataset_problem(load_config().cell, 1),
        PlanOptions(method="bh", heuristic=Heuristic.TLF, sort=Sort.CIF),
    )
    assert out.splitlines()[0].startswith(f"bh: {expected.n} of 12 mugs placed in ")
    assert f"left on the counter: {', '.join(expected.unplaced)}" in out


def test_pictures_are_written(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    svg, png = tmp_path / "plan.svg", tmp_path / "plan.png"
    code, _, _ = run(capsys, "--dataset", "6", "--footprint", "rect", "--svg", str(svg), "--png", str(png))
    assert code == 0
    assert svg.read_text().startswith("<svg ")
    assert svg.read_text().count("<circle") == 23
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.png", "plan.svg"]


@pytest.mark.parametrize(
    ("content", "extra", "message"),
    [
        (
            "{nope",
            [],
            "{path}: not valid JSON: Expecting property name enclosed in double quotes at line 1 column 2",
        ),
        (
            json.dumps({**EXAMPLE, "mugs": [{"id": "m1", "type": "huge", "x_mm": 0, "y_mm": 0}]}),
            [],
            "{path}: mugs[0].type: unknown mug type 'huge' (known: big, small)",
        ),
        (
            json.dumps({**EXAMPLE, "tray": {"size_mm": [475, -5]}}),
            [],
            "{path}: tray.size_mm[1]: -5 is out of range; allowed (0, 10000] mm",
        ),
        (
            json.dumps({**EXAMPLE, "tray": {"size_mm": ["wide", 520]}}),
            [],
            "{path}: tray.size_mm[0]: expected a number in (0, 10000] mm, got 'wide'",
        ),
        (
            json.dumps({**EXAMPLE, "tray": {"size_mm": [100, 100]}}),
            [],
            "{path}: mugs[0].type: a 'big' mug (130 x 101 mm with tolerance) is larger than the tray"
            " (100 x 100 mm)",
        ),
        (
            json.dumps({**EXAMPLE, "placed": EXAMPLE["placed"] * 2}),
            [],
            "{path}: placed[1].id: duplicate mug id 'p1'",
        ),
        (
            json.dumps({**EXAMPLE, "placed": [{"id": "p1", "type": "big", "x_mm": 400, "y_mm": 0}]}),
            [],
            "{path}: placed[0]: footprint [400, 530] x [0, 101] mm leaves the tray (475 x 520 mm)",
        ),
        (
            json.dumps(EXAMPLE),
            ["--time-limit", "0"],
            "--time-limit: must be a positive number of seconds, got '0'",
        ),
        (json.dumps(EXAMPLE), ["--time-limit", "soon"], "--time-limit: expected a number, got 'soon'"),
        (json.dumps(EXAMPLE), ["--seed", "1.5"], "--seed: expected a whole number, got '1.5'"),
        (
            json.dumps(EXAMPLE),
            ["--method", "magic"],
            "--method: unknown method 'magic' (known: auto, exact, bh, sa, ga, psop-n, psop-i, psok-n,"
            " psok-i)",
        ),
        (
            json.dumps(EXAMPLE),
            ["--heuristic", "zigzag"],
            "--heuristic: unknown heuristic 'zigzag' (known: blf, lbf, tlf, ltf, brf, rbf, trf, rtf)",
        ),
        (
            json.dumps(EXAMPLE),
            ["--sort", "size"],
            "--sort: unknown sort 'size' (known: cif, nis-l, nis-w, nds-l, nds-w, ro)",
        ),
        (
            json.dumps(EXAMPLE),
            ["--cost", "cheap"],
            "--cost: unknown cost function 'cheap' (known: bpc, upc, ec)",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str, extra: list[str], message: str
) -> None:
    problem = tmp_path / "problem.json"
    problem.write_text(content)
    svg = tmp_path / "out.svg"
    code, out, err = run(capsys, str(problem), "--svg", str(svg), *extra)
    assert code == 2
    assert out == ""
    assert err == f"dishbot plan: error: {message.format(path=problem)}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["problem.json"]


def test_missing_file_and_unknown_dataset_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert (
        run(capsys, str(tmp_path / "absent.json"))[2]
        == f"dishbot plan: error: {tmp_path / 'absent.json'}: no such file\n"
    )
    assert (
        run(capsys, "--dataset", "9")[2]
        == "dishbot plan: error: --dataset: unknown dataset '9' (known: 1-6)\n"
    )
    assert run(capsys)[2] == "dishbot plan: error: give a PROBLEM.json (or - for stdin) or --dataset N\n"
    assert run(capsys, "x.json", "--dataset", "1")[2] == (
        "dishbot plan: error: give either PROBLEM.json or --dataset N, not both\n"
    )
    code, _, err = run(capsys, "--dataset", "1", "--png", str(tmp_path / "no" / "dir.png"))
    assert (code, err) == (
        2,
        f"dishbot plan: error: --png: directory {str(tmp_path / 'no')!r} does not exist\n",
    )


def test_own_weights_and_ranking_are_taken_and_checked(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(
        capsys,
        "--dataset",
        "1",
        "--method",
        "bh",
        "--fitness",
        "ws",
        "--weights",
        "n=1,E=0,t=0,s=0",
        "--json",
    )
    assert (code, json.loads(out)["fitness"]) == (0, "ws")
    code, _, _ = run(capsys, "--dataset", "1", "--method", "bh", "--ranking", "E,n,t,s")
    assert code == 0
    assert run(capsys, "--dataset", "1", "--weights", "n=lots")[2] == (
        "dishbot plan: error: --weights: expected name=number pairs like n=0.4,E=0.3, got 'n=lots'\n"
    )
    assert run(capsys, "--dataset", "1", "--weights", "q=1")[2] == (
        "dishbot plan: error: weights: unknown parameter 'q' (known: n, E, t, s)\n"
    )
    assert run(capsys, "--dataset", "1", "--weights", "n=-1")[2] == (
        "dishbot plan: error: weights.n: must be a number, 0 or more, got -1.0\n"
    )
    assert run(capsys, "--dataset", "1", "--ranking", "n,size")[2] == (
        "dishbot plan: error: ranking: unknown parameter 'size' (known: n, A, E, t, s)\n"
    )


@pytest.mark.slow
def test_footprint_flag_plans_mug_shapes_with_brims_and_handles(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    svg = tmp_path / "plan.svg"
    code, out, _ = run(capsys, "--dataset", "2", "--footprint", "mug", "--json", "--svg", str(svg))
    assert code == 0
    doc = json.loads(out)
    assert doc["n"] > 8  # the rectangle optimum
    for p in doc["placed"]:
        assert len(p["brim_mm"]) == 2
        assert -math.pi <= p["handle_yaw_rad"] <= math.pi
    picture = svg.read_text()
    assert picture.count("<circle") == doc["n"]
    assert picture.count('stroke-linecap="round"') == doc["n"]  # one handle per mug
    assert "stroke-dasharray" not in picture  # no rectangle footprints drawn
    assert "tray 332 x 374 mm" in picture


def test_an_unknown_footprint_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "--dataset", "1", "--footprint", "round")
    assert (code, out) == (2, "")
    assert err == "dishbot plan: error: --footprint: unknown footprint 'round' (known: rect, mug)\n"


@pytest.mark.slow
def test_the_problem_files_footprint_stands_unless_the_flag_says_otherwise(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    problem = tmp_path / "problem.json"
    problem.write_text(json.dumps({**EXAMPLE, "footprint": "mug"}))
    code, out, _ = run(capsys, str(problem), "--method", "bh")
    assert code == 0
    assert "note: mug-shaped: 1 from the rectangle layout" in out
    code, out, _ = run(capsys, str(problem), "--method", "bh", "--footprint", "rect")
    assert code == 0
    assert "mug-shaped" not in out


@pytest.mark.slow
def test_the_plan_verb_imports_only_what_its_path_uses(tmp_path: Path) -> None:
    """No OpenCV without a PNG, no OR-Tools or pandas when no exact model runs, no scipy.optimize at all."""
    problem = tmp_path / "problem.json"
    problem.write_text(json.dumps(EXAMPLE))
    heavy = ("cv2", "ortools", "pandas", "scipy.optimize")
    script = (
        "import sys\nfrom cli.main import main\n"
        f"code = main(['plan', {str(problem)!r}, '--method', 'bh', '--footprint', 'rect', '--json'])\n"
        f"print(code, sorted(m for m in {heavy!r} if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert done.stdout.splitlines()[-1] == "0 []"
    png = tmp_path / "plan.png"
    script = script.replace("'--json'", f"'--json', '--png', {str(png)!r}")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert done.stdout.splitlines()[-1] == "0 ['cv2']"


@pytest.mark.slow
def test_numpy_loads_with_openblas_on_one_thread_and_the_environment_as_it_was() -> None:
    """OpenBLAS starts a thread per core as numpy loads (they spin, about 30 ms of CPU) unless told
    otherwise; the plan verb tells it, and puts the variable back. (On a one-core machine OpenBLAS starts
    no thread either way.)"""
    script = (
        "import os, sys\nfrom cli.main import main\n"
        "code = main(['plan', '--dataset', '1', '--footprint', 'rect', '--json'])\n"
        "print(code, len(os.listdir('/proc/self/task')), os.environ.get('OPENBLAS_NUM_THREADS'))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        check=True,
        env={**env, "DISHBOT_CACHE_DIR": ""},
    )
    assert done.stdout.splitlines()[-1] == "0 1 None"


@pytest.mark.slow
def test_the_plan_command_ends_without_the_interpreters_teardown_its_output_whole(tmp_path: Path) -> None:
    """Run as the process's command, ``dishbot plan`` ends once its output is flushed: no teardown (an
    exit handler never runs), the same JSON and exit codes as when ``main`` returns."""

    def command(*argv: str) -> subprocess.CompletedProcess[str]:
        script = (
            "import atexit, sys\nfrom cli.main import main\n"
            "atexit.register(lambda: print('teardown', file=sys.stderr))\n"
            f"sys.argv = ['dishbot', *{list(argv)!r}]\nsys.exit(main())\n"
        )
        env = {**os.environ, "DISHBOT_CACHE_DIR": ""}
        return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)

    done = command("plan", "--dataset", "1", "--footprint", "rect", "--json")
    assert (done.returncode, done.stderr) == (0, "")
    assert json.loads(done.stdout)["n"] == 10
    bad = command("plan", "--dataset", "9")
    assert bad.returncode == 2
    assert bad.stderr == "dishbot plan: error: --dataset: unknown dataset '9' (known: 1-6)\n"
    # a verb without quick_exit tears down as before (main(argv) returns: the test above)
    assert "teardown" in command("statechart").stderr
