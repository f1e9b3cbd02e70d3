"""Fixtures for the perception tests: the default cell layout and rendered scenes."""

from __future__ import annotations

import tomllib
from importlib import resources

import pytest

from drivers.simworld.scene import SceneLayout


def default_layout() -> SceneLayout:
    """The cell of the embedded default config."""
    text = resources.files("daemon").joinpath("default_config.toml").read_text(encoding="utf-8")
    data = tomllib.loads(text)
    return SceneLayout.from_config(data["cell"], data["camera"])


@pytest.fixture(scope="session")
def layout() -> SceneLayout:
    return default_layout()
