"""No module reads or waits on the wall clock behind the clock seam's back (issue 11).

Everything reads time from the ``Clock`` it was constructed with (``drivers.interfaces.Clock``, implemented
in ``daemon.clock``). This scans every module of the packages for the wall clock's readers and waits —
``time.time``/``monotonic``/``perf_counter``/``sleep`` and the rest, ``datetime.now``, ``asyncio.sleep``,
``asyncio.wait_for``/``timeout``, ``asyncio.wait(..., timeout=)``, ``loop.time()`` — and allows them only
in the clock module, the benchmarks (they measure this machine) and the few functions below, each with the
reason the wall clock is the right clock there.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES: Final = (
    "description",
    "drivers",
    "perception",
    "planning",
    "statechart",
    "sim",
    "wire",
    "recorder",
    "daemon",
    "replay",
    "cli",
)

WALL_CLOCK: Final = {
    "time": {
        "time",
        "time_ns",
        "monotonic",
        "monotonic_ns",
        "perf_counter",
        "perf_counter_ns",
        "process_time",
        "process_time_ns",
        "thread_time",
        "thread_time_ns",
        "sleep",
        "clock_gettime",
        "clock_gettime_ns",
    },
    "datetime": {"now", "utcnow", "today"},
    "date": {"today"},
    "asyncio": {"sleep", "wait_for", "timeout", "timeout_at"},
}

# (module, function qualname) -> why the wall clock is right there. A module name alone allows it all.
ALLOWED: Final[dict[tuple[str, str], str]] = {
    ("daemon/clock.py", "*"): "the clock seam itself: the wall clock's one reader",
    ("drivers/dynamixel/bus.py", "WallWaits.now"): (
        "the bus's waits on a serial adapter (a status packet's timeout), in wall time like dynamixel-sdk's "
        "own packet timeouts; on a simulated clock ServoChain gives the bus waits in simulated time"
    ),
    ("drivers/dynamixel/bus.py", "WallWaits.sleep"): (
        "a rebooting servo's settle time, a re-enumerating USB adapter, on the bus thread"
    ),
    ("drivers/sim/servo_chain.py", "ServoChainSimulator._wire_delay"): (
        "the pty transport's wire time: a chain on a pty answers in wall-clock time"
    ),
    ("drivers/sim/servo_chain.py", "ServoChainSimulator._serve"): (
        "when the pty transport heard an instruction: its answers' wire time counts from there"
    ),
    ("drivers/sim/servo_chain.py", "_wall"): "the default plant of a chain on a pty (dishbot sim bus)",
    ("drivers/sim/fsr.py", "FsrSimulator._serve"): "the pty transport's thread streams in wall-clock time",
    ("sim/mujoco/world.py", "SimWorld._run"): (
        "the world's own thread, for the pty transport: real time x speed"
    ),
    ("sim/mujoco/world.py", "SimWorld._step_to_clock"): (
        "measures how long stepping took on this machine (wall_stepping_s), nothing else"
    ),
    ("recorder/writer.py", "Recorder._run"): (
        "how often the writer thread flushes to disk: the disk's time, whatever clock the session runs on"
    ),
    ("recorder/files.py", "Retention.apply"): (
        "file ages are the files' modification times, facts of the file system, against the wall clock"
    ),
    ("cli/commands/record.py", "run_plot"): "says how long drawing took on this machine, nothing else",
    ("cli/commands/monitor.py", "*"): (
        "a remote client: its redraws, its reconnection and when it last heard a daemon, in wall time"
    ),
    ("replay/faults.py", "_stall"): (
        "the loop_stall fault blocks the event loop for wall-clock time on purpose: a stall is the wall "
        "time the loop does not run, whatever clock the session is on"
    ),
    ("cli/credentials.py", "write"): "a certificate is valid from now on the wall clock, as TLS checks it",
    ("perception/observer.py", "CameraObserver._look"): (
        "measures how long detection took (the observation's detect_ms), nothing else"
    ),
    ("planning/placement/context.py", "Context.__init__"): (
        "measures how long a plan took (its wall_time_s and t), nothing else: budgets are deterministic time"
    ),
    ("planning/placement/context.py", "Context.elapsed"): "the same measurement",
    ("planning/placement/checked.py", "plan_checked"): (
        "measures how long packing and the arm's check took together (the plan's elapsed_s), nothing else"
    ),
    ("planning/placement/mugshaped.py", "run"): (
        "the mug packer's compute budget (CPU time of its thread): how long it may search on this machine"
    ),
    ("cli/commands/client.py", "_send"): (
        "a remote client: whether a query ended at once (refused by access control) or ran to its timeout, "
        "in wall time as Zenoh's query timeout"
    ),
}


@dataclass(frozen=True, slots=True)
class Use:
    module: str
    function: str
    line: int
    what: str

    def __str__(self) -> str:
        return f"{self.module}:{self.line} in {self.function}: {self.what}"


def wall_clock_uses(source: str, module: str) -> Iterator[Use]:
    """Every read of or wait on the wall clock in ``source``, with the function it is in."""
    tree = ast.parse(source)
    for node, function in _walk(tree, ""):
        what = _wall_clock(node)
        if what is not None:
            yield Use(module, function or "<module>", getattr(node, "lineno", 0), what)


def _walk(node: ast.AST, function: str) -> Iterator[tuple[ast.AST, str]]:
    for child in ast.iter_child_nodes(node):
        name = function
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            name = f"{function}.{child.name}" if function else child.name
        yield child, name
        yield from _walk(child, name)


def _wall_clock(node: ast.AST) -> str | None:
    if (
        isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.attr in WALL_CLOCK.get(node.value.id, set())
    ):
        return f"{node.value.id}.{node.attr}"
    if (
        isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Attribute)
        and isinstance(node.value.value, ast.Name)
        and node.value.value.id == "datetime"
        and node.attr in WALL_CLOCK.get(node.value.attr, set())
    ):
        return f"datetime.{node.value.attr}.{node.attr}"
    if isinstance(node, ast.ImportFrom) and node.module in WALL_CLOCK:
        names = [a.name for a in node.names if a.name in WALL_CLOCK[node.module]]
        if names:
            return f"from {node.module} import {', '.join(names)}"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
        func = node.func
        if (
            isinstance(func.value, ast.Name)
            and func.value.id == "asyncio"
            and func.attr == "wait"
            and any(k.arg == "timeout" for k in node.keywords)
        ):
            return "asyncio.wait(..., timeout=...)"
        if func.attr == "time" and not node.args and _is_loop(func.value):
            return f"{ast.unparse(func.value)}.time()"
    return None


def _is_loop(node: ast.expr) -> bool:
    """``loop``, ``self._loop``, ``asyncio.get_running_loop()``: an event loop."""
    if isinstance(node, ast.Call):
        return isinstance(node.func, ast.Attribute) and node.func.attr in (
            "get_running_loop",
            "get_event_loop",
        )
    text = ast.unparse(node)
    return text.split(".")[-1].lstrip("_").endswith("loop")


def _allowed(use: Use) -> bool:
    return (use.module, "*") in ALLOWED or (use.module, use.function) in ALLOWED


def _project_uses() -> list[Use]:
    uses: list[Use] = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            module = path.relative_to(ROOT).as_posix()
            uses.extend(wall_clock_uses(path.read_text(encoding="utf-8"), module))
    return uses


def test_no_module_reads_the_wall_clock_behind_the_clock_seam() -> None:
    behind = [str(u) for u in _project_uses() if not _allowed(u)]
    assert behind == [], "wall-clock reads outside the clock seam:\n" + "\n".join(behind)


def test_every_allowed_wall_clock_use_is_still_there() -> None:
    used = {(u.module, u.function) for u in _project_uses()} | {(m, "*") for m, _ in ALLOWED}
    stale = sorted(f"{m} {f}" for m, f in ALLOWED if (m, f) not in used)
    assert stale == [], "allow-list entries no longer needed: " + ", ".join(stale)


@pytest.mark.parametrize(
    ("source", "found"),
    [
        ("import time\ndef f():\n    return time.monotonic()\n", "time.monotonic"),
        ("import time\nclass A:\n    t: float = field(default_factory=time.time)\n", "time.time"),
        ("import asyncio\nasync def f():\n    await asyncio.sleep(1)\n", "asyncio.sleep"),
        (
            "import asyncio\nasync def f(x):\n    await asyncio.wait({x}, timeout=1)\n",
            "asyncio.wait(..., timeout=...)",
        ),
        ("import asyncio\nasync def f(x):\n    await asyncio.wait_for(x, 1)\n", "asyncio.wait_for"),
        ("def f(self):\n    return self._loop.time()\n", "self._loop.time()"),
        (
            "import asyncio\ndef f():\n    return asyncio.get_running_loop().time()\n",
            "asyncio.get_running_loop().time()",
        ),
        ("from time import perf_counter\n", "from time import perf_counter"),
        ("import datetime\ndef f():\n    return datetime.datetime.now()\n", "datetime.datetime.now"),
        ("from datetime import datetime\ndef f():\n    return datetime.now()\n", "datetime.now"),
    ],
)
def test_the_scan_finds_each_kind_of_wall_clock_read(source: str, found: str) -> None:
    assert [u.what for u in wall_clock_uses(source, "m.py")] == [found]


def test_the_scan_leaves_the_clock_seam_and_other_times_alone() -> None:
    source = (
        "import asyncio, time\n"
        "async def f(clock, world, x):\n"
        "    await clock.sleep(1)\n"
        "    t = clock.monotonic() + world.time()\n"
        "    await asyncio.wait({x})\n"
        "    return time.gmtime(t)\n"
    )
    assert list(wall_clock_uses(source, "m.py")) == []
