"""``dishbot bench replay``: bad flags are refused in one clear line before anything is recorded, and the
robot rig's sessions (``--rig N``) cover both rig worlds, several datasets, picks and seeds, with few mugs
(each job runs on the wall clock). The bench itself records on the rig: its figures are in
docs/recording.md."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.replay import rig_sessions
from cli.main import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--rig", "21"], "--rig 21 is out of range; allowed [0, 20]"),
        (["--rig", "-1"], "--rig -1 is out of range; allowed [0, 20]"),
        (["--sessions", "0,0,0"], "nothing to run: --sessions 0,0,0 and no --rig"),
        (["--sessions", "7,0,0"], "--sessions '7,0,0': K is 0-6 (datasets), M 0-3, P 0-5"),
        (["--sessions", "1,2"], "--sessions '1,2': give three counts K,M,P, e.g. 5,3,2"),
    ],
)
def test_bad_flags_exit_2_with_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "replay", *argv]) == 2
    assert capsys.readouterr().err == f"dishbot bench: error: {message}\n"


def test_keep_refuses_a_folder_with_files_in_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "mine.txt").write_text("x")
    assert main(["bench", "replay", "--rig", "1", "--keep", str(tmp_path)]) == 2
    assert (
        capsys.readouterr().err
        == f"dishbot bench: error: --keep {tmp_path}: exists and is not an empty folder; name a new one\n"
    )
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


def test_ten_rig_sessions_take_both_worlds_five_datasets_and_a_new_pick_each() -> None:
    planned = rig_sessions(10)
    assert [s.kind for s in planned] == ["rig-mujoco", "rig-kinematic"] * 5
    assert {s.dataset for s in planned} == {1, 2, 3, 4, 5}
    assert [s.seed for s in planned] == list(range(10))
    assert all(2 <= len(s.mugs) <= 3 for s in planned)
    assert sum(len(s.mugs) == 3 for s in planned) == 3
    assert len({(s.dataset, s.mugs) for s in planned}) == 10
    for s in planned:
        assert len({m[0] for m in s.mugs}) == len(s.mugs)
        for _, kind, x, y in s.mugs:
            assert kind in ("big", "small")
            assert x >= -0.26
            assert y <= 0.53
