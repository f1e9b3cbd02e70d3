"""``dishbot bench sim``: bad flags are refused in one clear line (the cell it runs on comes from the daemon's
builder: ``tests/daemon/test_backend_builder.py``)."""

from __future__ import annotations

import pytest

from cli.main import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--datasets", "7"], "--datasets: unknown dataset '7' (datasets 1-6)"),
        (["--datasets", ","], "--datasets: name at least one of 1, 2, 3"),
        (["--timeout", "0"], "--timeout: 0.0 must be > 0 seconds"),
        (["--fsr-debounce", "-1"], "--fsr-debounce: -1.0 must be in [0, 1] seconds"),
    ],
)
def test_bad_flags_exit_2_with_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "sim", *argv]) == 2
    assert capsys.readouterr().err == f"dishbot bench: error: {message}\n"
