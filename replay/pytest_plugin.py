"""dishbot's pytest plugin: record a simulated session, replay it with faults, and look at what happened.

Installed with dishbot (entry point ``pytest11``: ``dishbot``), it gives tests one fixture, ``dishbot``::

    def test_the_job_survives_a_slip(dishbot):
        session = dishbot.record(world="kinematic", dataset=1, seed=0)
        trace = dishbot.replay(session, faults=[{"kind": "mug_slip", "at_state": "flip.transit"}])
        assert trace.faults[0]["kind"] == "mug_slip"
        assert trace.final_state == "done"

``record`` runs one job on the simulated cell and returns its recording (the same arguments give the same
file: recordings are kept for the whole test session, keyed by their arguments); ``load`` reads a
recording of your own; ``replay`` re-runs it through the daemon with faults from a TOML file, TOML text or
a list of tables, and returns a ``ReplayTrace`` (``replay.harness``): the states entered in order, the events
by kind, the final state, the faults fired, where the replay first diverged and the replay's own recording.

pytest loads this module in every environment where dishbot is installed, so it imports nothing of dishbot's
(no Zenoh, NumPy, SciPy, Pinocchio or MuJoCo) until a test asks for the fixture.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from replay.harness import DishbotReplay


@pytest.fixture(scope="session")
def _dishbot_recordings() -> dict[str, Path]:
    return {}


@pytest.fixture
def dishbot(
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
    _dishbot_recordings: dict[str, Path],
) -> DishbotReplay:
    """Record simulated sessions, replay them with faults, get their traces (``replay.harness``)."""
    from replay.harness import DishbotReplay

    name = re.sub(r"[^\w-]", "_", request.node.name)[:40]
    return DishbotReplay(tmp_path_factory.mktemp(f"dishbot-{name}"), _dishbot_recordings)
