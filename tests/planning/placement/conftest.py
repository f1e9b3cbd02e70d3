"""Every placement test keeps what ``dishbot plan`` caches (``planning.placement.cache``) in a folder of its
own, so no test reads what another run kept and none writes to the user's cache."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _own_plan_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path_factory.mktemp("plan-cache")
    monkeypatch.setenv("DISHBOT_CACHE_DIR", str(folder))
    return folder
