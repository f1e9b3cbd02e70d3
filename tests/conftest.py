"""Shared fixtures for the dishbot test suite."""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Iterator
from importlib.metadata import entry_points
from typing import Any

import pytest
import structlog

# pytester: the tests of the pytest plugin dishbot ships run pytest inside pytest. The plugin itself comes
# with the installed package (entry point pytest11 "dishbot"); an install older than the entry point gets
# it by name.
pytest_plugins = ["pytester", "tests.fakes.slow_guard"]
if not any(e.name == "dishbot" for e in entry_points(group="pytest11")):
    pytest_plugins.append("replay.pytest_plugin")

# MuJoCo renders offscreen without a GPU through EGL (Mesa llvmpipe); set before any mujoco import.
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(autouse=True)
def _own_plan_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """What ``dishbot plan`` keeps between runs (``planning.placement.cache``) goes to a folder of the test's
    own (its subprocesses inherit it): no test reads what another run kept, none writes to the user's."""
    monkeypatch.setenv("DISHBOT_CACHE_DIR", str(tmp_path_factory.mktemp("plan-cache")))


# Each test's last time (setup, call and teardown, in seconds), kept in pytest's cache (.pytest_cache) by the
# runs before: under pytest-xdist the costliest work goes out first (see pytest_collection_modifyitems).
DURATIONS_KEY = "dishbot/durations"
# A test the cache does not know yet (a fresh clone): a slow one counts as this many seconds, another as 0.1.
UNKNOWN_SLOW_S = 10.0
UNKNOWN_FAST_S = 0.1


def pytest_configure(config: pytest.Config) -> None:
    """pytest-xdist's controller hands the work out in the order the workers collected it (not sorted by the
    size of the groups, its default): the order pytest_collection_modifyitems gives, from the times the
    controller read from the cache and sent to every worker (so they agree even if another run writes the
    cache meanwhile). Every run but a worker's notes the tests' times in the cache for the next run."""
    if hasattr(config, "workerinput"):
        config.pluginmanager.register(_GroupIds(), "dishbot-group-ids")
        return
    if getattr(config.option, "dist", "no") == "loadgroup":
        config.option.loadscopereorder = False
    cache = getattr(config, "cache", None)
    if cache is not None:
        config.pluginmanager.register(_Durations(cache), "dishbot-durations")


class _Durations:
    """Sends the times the cache holds to each pytest-xdist worker; collects each test's time from its
    reports (a worker's come to the controller) and merges them into the cache when the session ends: tests
    that did not run keep their time."""

    def __init__(self, cache: pytest.Cache) -> None:
        self.cache = cache
        self.known = _known_durations(cache)
        self.times: dict[str, float] = defaultdict(float)

    @pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: absent under -p no:xdist
    def pytest_configure_node(self, node: Any) -> None:
        node.workerinput[DURATIONS_KEY] = self.known

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.times[_ungrouped(report.nodeid)] += report.duration

    def pytest_sessionfinish(self) -> None:
        if self.times:
            known = _known_durations(self.cache)
            known.update({k: round(v, 3) for k, v in self.times.items()})
            self.cache.set(DURATIONS_KEY, known)


def _ungrouped(nodeid: str) -> str:
    """A test's id without the ``@group`` pytest-xdist appends under ``--dist loadgroup``."""
    return nodeid.rpartition("@")[0] if nodeid.rfind("@") > nodeid.rfind("]") else nodeid


def _known_durations(cache: pytest.Cache | None) -> dict[str, float]:
    found = cache.get(DURATIONS_KEY, {}) if cache is not None else {}
    if not isinstance(found, dict):
        return {}
    return {str(k): float(v) for k, v in found.items() if isinstance(v, (int, float))}


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's worker reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In a pytest-xdist worker (``scripts/test.sh``: ``-n N --dist loadgroup``), the tests of a module that
    share a module- or class-scoped fixture (a recorded session, a booted systemd container, a pair of
    network namespaces) go into one group named after the module: they run on one worker, in file order,
    and the fixture is built once rather than once per worker. A test with its own ``xdist_group`` keeps it;
    the other tests spread over the workers one by one.

    Then the work goes out the costliest first (a group as one piece, its tests in file order): by the times
    of the runs before (pytest's cache, as the controller sent them), else a slow test as 10 s and another
    as 0.1 s. The long tests start
    at once on the free workers and the short ones fill in at the end, so the workers finish together
    rather than one running a 100 s test alone after the others are done. Every worker has the same times,
    so they agree on the order (pytest-xdist checks that they do)."""
    if not hasattr(config, "workerinput"):
        return
    for item in items:
        if not isinstance(item, pytest.Function) or item.get_closest_marker("xdist_group") is not None:
            continue
        scopes = {d.scope for defs in item._fixtureinfo.name2fixturedefs.values() for d in defs}
        if scopes & {"module", "class", "package"}:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.partition("::")[0]))
    known: dict[str, float] = config.workerinput.get(DURATIONS_KEY, {})
    units: dict[str, list[pytest.Item]] = {}
    for item in items:  # the work units pytest-xdist's loadgroup makes
        units.setdefault(_group_suffix(item) or item.nodeid, []).append(item)

    def cost(item: pytest.Item) -> float:
        default = UNKNOWN_SLOW_S if item.get_closest_marker("slow") is not None else UNKNOWN_FAST_S
        return known.get(item.nodeid, default)

    ordered = sorted(units.values(), key=lambda unit: -sum(cost(i) for i in unit))
    items[:] = [item for unit in ordered for item in unit]


def _group_suffix(item: pytest.Item) -> str:
    """What pytest-xdist's loadgroup appends to the id of a test in a group: ``@`` and the test's group
    names, sorted and joined by ``_``; empty for a test in no group."""
    groups = sorted(
        {
            str(m.args[0] if m.args else m.kwargs.get("name", "default"))
            for m in item.iter_markers("xdist_group")
        }
    )
    return "@" + "_".join(groups) if groups else ""


class _GroupIds:
    """pytest-xdist's worker tells the controller a test's group by the ``@group`` it appends to the test's
    id, written to the field pytest kept the id in before 9.2 (``_nodeid``). pytest 9.2 reads the id from a
    structured one (``_id``), so the suffix was lost and ``--dist loadgroup`` silently spread every group
    over all workers (pytest-xdist issue 1386): each worker built a module's fixture again (a recording, a
    booted container) and the ``realtime-pty`` tests ran side by side. After pytest-xdist's own hook, this
    puts the suffix where pytest reads the id, unless it is there already (an older pytest, a fixed
    pytest-xdist)."""

    @pytest.hookimpl(trylast=True)
    def pytest_collection_modifyitems(self, config: pytest.Config, items: list[pytest.Item]) -> None:
        if not config.getvalue("loadgroup"):
            return
        for item in items:
            suffix = _group_suffix(item)
            if suffix and not item.nodeid.endswith(suffix):
                item._id = type(item._id).parse(item.nodeid + suffix)


@pytest.fixture(autouse=True)
def _structlog_defaults() -> Iterator[None]:
    """CLI verbs point structlog at the stderr of the moment (a capture that closes after the test); later
    tests must not log into it."""
    yield
    structlog.reset_defaults()
