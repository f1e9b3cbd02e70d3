"""``dishbot bench placement`` runs and reports the thesis's figures beside its own (a smoke run)."""

from __future__ import annotations

import json

import pytest

from cli.main import main


def test_bench_reports_each_method_with_the_thesis_figures(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(
        ["bench", "placement", "--runs", "2", "--datasets", "2", "--methods", "bh,exact,auto", "--json"]
    )
    out, _ = capsys.readouterr()
    assert code == 0
    doc = json.loads(out)
    rows = {r["method"]: r for r in doc["rows"]}
    assert set(rows) == {"bh", "exact", "auto"}
    assert rows["exact"]["placed"] == "8.00 ± 0.00"
    assert rows["exact"]["optimum"] == 8
    assert rows["bh"]["thesis_s"] == pytest.approx(0.006)
    assert rows["bh"]["thesis_best"] == 8
    assert doc["exact_proves_all"] is True
    (speed,) = doc["packer_speed"]
    assert speed["identical"] is True


def test_bench_refuses_an_unknown_method(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "placement", "--methods", "sa,magic"]) == 2
    assert capsys.readouterr().err == (
        "dishbot bench: error: --methods: unknown entry 'magic' (known: auto, exact, bh, sa, ga, psop-n,"
        " psop-i, psok-n, psok-i)\n"
    )
