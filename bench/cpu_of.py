"""The CPU time of a command with every process it starts counted: ``python -m bench.cpu_of -- CMD ...``.

``/usr/bin/time`` counts a process's children only once they are waited for. A job's planning worker is a
child of multiprocessing's forkserver, which reaps it and exits after the daemon without being waited for,
so neither's CPU reaches the daemon's ``RUSAGE_CHILDREN`` (about 2.4 s of a kinematic dataset-1 job,
docs/daemon.md). Here the process makes itself the subreaper of all its descendants (Linux
``PR_SET_CHILD_SUBREAPER``): an orphan is handed to it, not to init, and it waits for every one before it
reads ``RUSAGE_CHILDREN``. The command's output passes through; one line on stderr says what it cost, and
the exit status is the command's.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import subprocess
import sys
import time

_PR_SET_CHILD_SUBREAPER = 36


def become_subreaper() -> None:
    """Orphaned descendants are handed to this process from now on (Linux only)."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"prctl(PR_SET_CHILD_SUBREAPER) failed: {os.strerror(err)}")


def reap_all() -> None:
    """Wait for every descendant handed to this process, until none is left."""
    while True:
        try:
            os.wait()
        except ChildProcessError:
            return


def measure(command: list[str]) -> dict[str, float | int]:
    """Run ``command`` to its end and every process it started to theirs: exit status, CPU and wall."""
    become_subreaper()
    started = time.monotonic()
    status = subprocess.call(command)
    reap_all()
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {
        "exit_status": status,
        "user_s": round(usage.ru_utime, 3),
        "sys_s": round(usage.ru_stime, 3),
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 3),
        "wall_s": round(time.monotonic() - started, 3),
        "max_rss_mb": round(usage.ru_maxrss / 1024.0, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.cpu_of",
        description="Run a command; print the CPU time of it and of every process it started, orphans "
        "included (the planning worker, the forkserver), on stderr. The exit status is the command's.",
    )
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON line")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- CMD [ARGS ...]")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no command given: python -m bench.cpu_of -- CMD [ARGS ...]")
    if not sys.platform.startswith("linux"):
        parser.error("counting orphaned descendants needs Linux (PR_SET_CHILD_SUBREAPER)")
    try:
        figures = measure(command)
    except FileNotFoundError:
        parser.error(f"no such command: {command[0]}")
    if args.json:
        print(json.dumps(figures), file=sys.stderr)
    else:
        print(
            f"cpu {figures['cpu_s']:.2f} s (user {figures['user_s']:.2f}, sys {figures['sys_s']:.2f}), "
            f"wall {figures['wall_s']:.2f} s, largest process {figures['max_rss_mb']:.0f} MB, "
            f"exit {figures['exit_status']}",
            file=sys.stderr,
        )
    status = int(figures["exit_status"])
    return status if status >= 0 else 128 - status  # killed by signal N: 128 + N, as a shell says


if __name__ == "__main__":
    sys.exit(main())
