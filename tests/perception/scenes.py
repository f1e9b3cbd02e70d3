"""Rendering helpers for the perception tests: build a cell, render one frame, close the renderer."""

from __future__ import annotations

from collections.abc import Sequence

import mujoco

from description.cell import CellLayout, SceneMug
from drivers.interfaces import RGBDFrame
from sim.mujoco.camera import DepthCamera, DepthNoise
from sim.mujoco.scene import build_mjcf


def render(
    layout: CellLayout,
    mugs: Sequence[SceneMug],
    *,
    extra_body_xml: str = "",
    noise: DepthNoise | None = None,
    seed: int = 0,
    color: bool = False,
) -> RGBDFrame:
    """One frame of the cell with these mugs, seen by the configured depth camera."""
    model = mujoco.MjModel.from_xml_string(build_mjcf(layout, mugs, extra_body_xml=extra_body_xml))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = layout.camera
    with DepthCamera(
        model, data, width=cam.width, height=cam.height, noise=noise, seed=seed, color=color
    ) as c:
        return c.render()
