"""``dishbot arm fk|ik|workspace|calibrate``: output shapes, exit codes and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli.main import main


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["arm", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_fk_json_gives_position_and_rotation(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "fk", "0", "0", "0", "-1.5708", "-1.5708", "--json")
    assert code == 0
    doc = json.loads(out)
    assert set(doc) == {"position_m", "rotation"}
    assert doc["position_m"] == pytest.approx([0.7275, 0.0, 0.06], abs=1e-3)
    assert np.allclose(np.asarray(doc["rotation"]) @ np.asarray(doc["rotation"]).T, np.eye(3), atol=1e-9)


def test_ik_json_solution_round_trips_through_fk(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "ik", "0.5", "0.1", "0.2", "--grasp", "side", "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["ok"] is True
    assert len(doc["q_rad"]) == 5
    assert doc["residual_m"] <= 1e-3
    code, out, _ = _run(capsys, "fk", *(repr(v) for v in doc["q_rad"]), "--json")
    assert json.loads(out)["position_m"] == pytest.approx([0.5, 0.1, 0.2], abs=1e-3)


def test_ik_without_a_solution_exits_1_with_the_reason(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "ik", "0.9", "0", "0.06", "--grasp", "side", "--json")
    assert code == 1
    assert json.loads(out) == {
        "ok": False,
        "error": "out of reach for a side grasp: the wrist would be 0.750 m from the shoulder, "
        "the arm reaches 0.578 m",
    }


def test_ik_table_without_a_solution_explains_on_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _run(capsys, "ik", "0.9", "0", "0.06", "--grasp", "side")
    assert code == 1
    assert out == ""
    assert err.startswith("dishbot arm ik: no solution: out of reach for a side grasp")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (("ik", "abc", "0", "0"), "dishbot arm: error: X: 'abc' is not a number\n"),
        (("ik", "0.5", "nan", "0"), "dishbot arm: error: Y: must be a finite number, got 'nan'\n"),
        (
            ("fk", "0", "1", "0", "0", "0"),
            "dishbot arm: error: shoulder_lift=1.0000 rad is outside [-2.0000, 0.3000]\n",
        ),
        (("fk", "0", "0", "0", "0", "inf"), "dishbot arm: error: Q5: must be a finite number, got 'inf'\n"),
    ],
)
def test_bad_numbers_exit_2_naming_the_argument(
    capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], message: str
) -> None:
    code, out, err = _run(capsys, *argv)
    assert code == 2
    assert out == ""
    assert err == message


def test_a_missing_urdf_exits_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    missing = tmp_path / "arm.urdf"
    code, _, err = _run(capsys, "fk", "0", "0", "0", "0", "0", "--urdf", str(missing))
    assert code == 2
    assert (
        err == f"dishbot arm: error: --urdf: cannot read the arm URDF {missing}: No such file or directory\n"
    )


@pytest.mark.slow
def test_workspace_draws_the_cell_and_reports_it_reachable(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    png = tmp_path / "ws.png"
    code, out, _ = _run(capsys, "workspace", "--png", str(png), "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["cell_unreachable"] == []
    assert doc["served_tray"]["size_mm"][0] >= 300
    image = cv2.imread(str(png))
    assert image is not None
    assert image.shape[0] > 500


@pytest.mark.slow
def test_workspace_with_an_unreachable_tray_exits_1(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    config = tmp_path / "cell.toml"
    config.write_text("[cell]\ntray_origin_m = [0.05, -0.187]\n", encoding="utf-8")
    code, out, _ = _run(capsys, "workspace", "--config", str(config))
    assert code == 1
    assert "configured cell: unreachable points:\n  tray point (0.1" in out


def test_calibrate_writes_a_correction(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    commanded = np.column_stack(
        [rng.uniform(0.35, 0.6, 20), rng.uniform(0.0, 0.4, 20), rng.choice([0.06, 0.2], 20)]
    )
    reached = commanded + np.array([0.01, -0.005, 0.002])
    pairs = tmp_path / "pairs.json"
    pairs.write_text(
        json.dumps(
            {
                "pairs": [
                    {"commanded": list(c), "reached": list(r)}
                    for c, r in zip(commanded, reached, strict=True)
                ]
            }
        ),
        encoding="utf-8",
    )
    out_file = tmp_path / "correction.json"
    code, out, _ = _run(capsys, "calibrate", str(pairs), "--out", str(out_file))
    assert code == 0
    assert out.startswith("pairs: 20\nrms error before: 11.36 mm, after: 0.00 mm")
    assert json.loads(out_file.read_text(encoding="utf-8"))["x"][0] == pytest.approx(0.01)


def test_calibrate_with_too_few_pairs_exits_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    pairs = tmp_path / "pairs.json"
    pairs.write_text(
        '{"pairs": [{"commanded": [0.4, 0, 0.06], "reached": [0.41, 0, 0.06]}]}', encoding="utf-8"
    )
    code, _, err = _run(capsys, "calibrate", str(pairs))
    assert code == 2
    assert err == "dishbot arm: error: need at least 14 calibration pairs, got 1\n"
