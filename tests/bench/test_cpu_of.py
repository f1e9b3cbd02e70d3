"""``python -m bench.cpu_of``: a command's CPU with the processes it left behind counted."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

# The command forks a child that outlives it: the command exits 3 at once, its orphan then burns 0.3 s
# of CPU. Waiting for the command alone (as /usr/bin/time does) counts none of that.
ORPHAN_BURNS = textwrap.dedent(
    """
    import os, time
    if os.fork() == 0:
        os.setsid()
        time.sleep(0.05)
        t = time.process_time()
        while time.process_time() - t < 0.3:
            pass
        os._exit(0)
    os._exit(3)
    """
)


def cpu_of(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bench.cpu_of", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.slow
def test_the_cpu_of_an_orphaned_descendant_is_counted_and_the_exit_status_passes_through() -> None:
    done = cpu_of("--json", "--", sys.executable, "-c", ORPHAN_BURNS)
    assert done.returncode == 3
    figures = json.loads(done.stderr)
    assert figures["exit_status"] == 3
    assert figures["cpu_s"] >= 0.3
    assert figures["cpu_s"] == pytest.approx(figures["user_s"] + figures["sys_s"], abs=0.002)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "error"),
    [
        ((), "no command given"),
        (("--",), "no command given"),
        (("--", "/nonexistent/command"), "no such command: /nonexistent/command"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args: tuple[str, ...], error: str) -> None:
    done = cpu_of(*args)
    assert done.returncode == 2
    assert f"error: {error}" in done.stderr.strip().splitlines()[-1]
