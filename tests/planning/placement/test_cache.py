"""What the planner keeps between runs (``planning.placement.cache``): a kept rectangle optimum or scan
order gives the very plan the work itself gives, a damaged file is passed over, and the key moves with what
the answer depends on."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planning.placement import PlanOptions, cache, cpsat, dataset_problem, mugpack, plan
from planning.placement.mugpack import MugPacker


def _plan(problem: Any, cache_dir: Path | None) -> dict[str, object]:
    doc = plan(problem, PlanOptions(cache_dir=cache_dir)).to_json()
    del doc["wall_time_s"], doc["t"]  # what the run took; nothing else may change
    return doc


def _no_solver(*_: object, **__: object) -> cpsat.Solution:
    raise AssertionError("the kept outcome should have answered")


@pytest.mark.parametrize("footprint", ["rect", "mug"])
def test_a_kept_rectangle_optimum_gives_the_same_plan_without_solving(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, footprint: str
) -> None:
    problem = replace(dataset_problem(2), footprint_kind=footprint)
    fresh = _plan(problem, None)
    assert list(tmp_path.iterdir()) == []
    assert _plan(problem, tmp_path) == fresh  # solved, and kept
    assert len(list(tmp_path.glob("exact-*.json"))) == 1
    monkeypatch.setattr(cpsat, "solve", _no_solver)
    assert _plan(problem, tmp_path) == fresh  # read back
    # the counter positions are not part of the model: moved mugs ask the same question
    moved = replace(problem, mugs=tuple(replace(m, x_mm=m.x_mm - 40.0) for m in problem.mugs))
    assert _plan(moved, tmp_path)["n"] == fresh["n"]
    # another mix of mugs asks another question
    fewer = replace(problem, mugs=problem.mugs[:-1])
    with pytest.raises(AssertionError, match="kept outcome should have answered"):
        _plan(fewer, tmp_path)


def test_a_damaged_or_foreign_kept_file_is_passed_over_and_replaced(tmp_path: Path) -> None:
    problem = replace(dataset_problem(1), footprint_kind="rect")
    fresh = _plan(problem, tmp_path)
    [kept] = tmp_path.glob("exact-*.json")
    good = kept.read_text(encoding="utf-8")
    for damaged in (good[: len(good) // 2], good.replace(kept.stem[len("exact-") :], "0" * 64), "[]"):
        kept.write_text(damaged, encoding="utf-8")
        assert _plan(problem, tmp_path) == fresh
        assert kept.read_text(encoding="utf-8") == good
    # spots that are not spots are not an answer
    kept.write_text(good.replace('"small"', "7"), encoding="utf-8")
    assert _plan(problem, tmp_path) == fresh


def test_a_folder_that_cannot_be_written_changes_nothing(tmp_path: Path) -> None:
    problem = dataset_problem(3)
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder", encoding="utf-8")
    assert _plan(problem, blocker / "cache") == _plan(problem, None)


def test_kept_scan_orders_are_the_orders_the_packer_makes(tmp_path: Path) -> None:
    problem = replace(dataset_problem(1), footprint_kind="mug")
    made = MugPacker(problem)
    mugpack._kept_scan_orders.cache_clear()
    MugPacker(problem, cache_dir=tmp_path)
    files = sorted(tmp_path.glob("scans-*.npy"))
    assert len(files) == 2  # one per mug type
    mugpack._kept_scan_orders.cache_clear()
    read = MugPacker(problem, cache_dir=tmp_path)
    for g_made, g_read in zip(made.groups, read.groups, strict=True):
        assert set(g_read.order) == set(mugpack.SCANS)
        for scan in mugpack.SCANS:
            assert np.array_equal(g_read.order[scan], g_made.order[scan])
            assert not g_read.order[scan].flags.writeable
    # a truncated file is made again (and kept whole)
    size = files[0].stat().st_size
    files[0].write_bytes(files[0].read_bytes()[: size // 2])
    mugpack._kept_scan_orders.cache_clear()
    again = MugPacker(problem, cache_dir=tmp_path)
    assert files[0].stat().st_size == size
    for g_made, g_again in zip(made.groups, again.groups, strict=True):
        assert all(np.array_equal(g_again.order[s], g_made.order[s]) for s in mugpack.SCANS)
    mugpack._kept_scan_orders.cache_clear()


def test_the_cache_folder_comes_from_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("DISHBOT_CACHE_DIR", str(tmp_path))
    assert cache.default_dir() == tmp_path / "placement"
    monkeypatch.setenv("DISHBOT_CACHE_DIR", "")
    assert cache.default_dir() is None
    monkeypatch.delenv("DISHBOT_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.default_dir() == tmp_path / "xdg" / "dishbot" / "placement"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache.default_dir() == tmp_path / "home" / ".cache" / "dishbot" / "placement"


def test_the_key_names_the_question_the_code_and_the_build() -> None:
    q = {"tray": [332, 374]}
    k = cache.key(q, ("exact.py",), "1")
    assert k is not None
    assert len(k) == 64
    assert k == cache.key(dict(q), ("exact.py",), "1")
    assert k != cache.key({"tray": [332, 375]}, ("exact.py",), "1")
    assert k != cache.key(q, ("exact.py", "cpsat.py"), "1")
    assert k != cache.key(q, ("exact.py",), "2")
    assert cache.key(q, ("no-such-file.py",), "1") is None
    assert cache.ortools_build() is not None
