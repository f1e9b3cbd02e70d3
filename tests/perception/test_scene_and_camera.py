"""The static simulated cell and its depth camera: geometry, names, the thesis pose and the noise model."""

from __future__ import annotations

import math
from collections.abc import Iterator

import mujoco
import numpy as np
import pytest

from description.cell import THESIS_CAMERA_POSE, CellLayout, SceneMug, thesis_camera_pose
from description.thesis import BIG_MUG, SMALL_MUG
from sim.mujoco.camera import DepthCamera, DepthNoise
from sim.mujoco.scene import CAMERA_NAME, build_mjcf, mug_mesh

MUGS = (
    SceneMug("a", BIG_MUG, -0.20, 0.30, yaw_rad=0.5),
    SceneMug("b", SMALL_MUG, 0.10, 0.42, yaw_rad=2.0),
    SceneMug("c", BIG_MUG, 0.05, -0.30, upside_down=True),
    SceneMug("d", SMALL_MUG, 0.30, 0.00, yaw_rad=-1.0),
)


@pytest.fixture(scope="module")
def world(layout: CellLayout) -> tuple[object, object]:
    model = mujoco.MjModel.from_xml_string(build_mjcf(layout, MUGS))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


@pytest.fixture(scope="module")
def ideal_frame(world: tuple[object, object]) -> Iterator[object]:
    model, data = world
    with DepthCamera(model, data, noise=None) as cam:
        yield cam.render()


def _names(model: object, kind: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, kind, i) or "" for i in range(count)]


def test_every_mug_is_a_free_body_with_its_thesis_mass(world: tuple[object, object]) -> None:
    model, _ = world
    for mug in MUGS:
        body = model.body(f"mug/{mug.mug_id}")  # type: ignore[attr-defined]
        assert body.mass[0] == pytest.approx(mug.spec.mass_kg)
        assert model.jnt_type[body.jntadr[0]] == mujoco.mjtJoint.mjJNT_FREE  # type: ignore[attr-defined]


def test_scene_names_carry_their_owner_prefix(world: tuple[object, object]) -> None:
    model, _ = world
    geoms = _names(model, mujoco.mjtObj.mjOBJ_GEOM, model.ngeom)  # type: ignore[attr-defined]
    assert {"table/top", "flip_area", "tray/base", "tray/wall_near", "tray/wall_far"} <= set(geoms)
    assert {g.split("/")[1] for g in geoms if g.startswith("mug/")} == {"a", "b", "c", "d"}
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME) == 0


def test_duplicate_mug_ids_are_refused(layout: CellLayout) -> None:
    with pytest.raises(ValueError, match=r"mug ids must be unique, got \['a', 'a'\]"):
        build_mjcf(layout, [MUGS[0], MUGS[0]])


def test_mug_mesh_is_closed_and_faces_outwards() -> None:
    vertices, faces = mug_mesh(SMALL_MUG)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert set(counts.tolist()) == {2}  # every edge shared by exactly two triangles: watertight
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    signed_volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    r, h = 0.037, 0.080
    cup = math.pi * r * r * h - math.pi * (r - 0.004) ** 2 * (h - 0.006)
    assert signed_volume == pytest.approx(cup, rel=0.01)


def test_default_camera_stands_where_the_thesis_put_it(layout: CellLayout) -> None:
    assert thesis_camera_pose(layout) == pytest.approx(THESIS_CAMERA_POSE, abs=1e-3)


def test_camera_sees_counter_flip_area_and_tray_with_mugs_on_them(layout: CellLayout) -> None:
    K = layout.camera.intrinsics()
    camera_from_world = np.linalg.inv(layout.camera.world_from_camera())
    x0, y0, x1, y1 = layout.counter_region_m
    tx0, ty0, tx1, ty1 = layout.tray.region_m
    fx, fy = layout.flip_area_center_m
    fr = layout.flip_area_radius_m
    corners = [(x0, y0), (x0, y1), (x1, y0), (x1, y1), (tx0, ty0), (tx0, ty1), (tx1, ty0), (tx1, ty1)]
    corners += [(fx - fr, fy), (fx + fr, fy), (fx, fy - fr), (fx, fy + fr)]
    points = np.array([(x, y, z) for x, y in corners for z in (0.0, BIG_MUG.height_mm / 1000)])
    pc = points @ camera_from_world[:3, :3].T + camera_from_world[:3, 3]
    u = K.fx * pc[:, 0] / pc[:, 2] + K.cx
    v = K.fy * pc[:, 1] / pc[:, 2] + K.cy
    assert (pc[:, 2] > 0).all()
    assert ((u >= 5) & (u <= K.width - 6) & (v >= 5) & (v <= K.height - 6)).all()


def test_rendered_table_pixels_back_project_onto_the_table_plane(
    ideal_frame: object, layout: CellLayout
) -> None:
    frame = ideal_frame
    K = frame.intrinsics  # type: ignore[attr-defined]
    depth = frame.depth_m  # type: ignore[attr-defined]
    T = frame.world_from_camera  # type: ignore[attr-defined]
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    z = depth.astype(np.float64)
    pc = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z], axis=-1)[z > 0]
    pw = pc @ T[:3, :3].T + T[:3, 3]
    x0, y0, x1, y1 = layout.table_region_m
    inside = (pw[:, 0] > x0 + 0.01) & (pw[:, 0] < x1 - 0.01) & (pw[:, 1] > y0 + 0.01) & (pw[:, 1] < y1 - 0.01)
    tx0, ty0, tx1, ty1 = layout.tray.region_m
    on_tray = (
        (pw[:, 0] > tx0 - 0.02) & (pw[:, 0] < tx1 + 0.02) & (pw[:, 1] > ty0 - 0.02) & (pw[:, 1] < ty1 + 0.02)
    )
    fx, fy = layout.flip_area_center_m
    on_flip = np.hypot(pw[:, 0] - fx, pw[:, 1] - fy) < layout.flip_area_radius_m + 0.005
    near_mug = np.zeros(len(pw), dtype=bool)
    for mug in MUGS:
        near_mug |= np.hypot(pw[:, 0] - mug.x_m, pw[:, 1] - mug.y_m) < 0.08
    table = pw[inside & ~on_tray & ~on_flip & ~near_mug & (np.abs(pw[:, 2]) < 0.01)]
    # The table top is the biggest surface in view; its pixels land on z = 0 to well under a millimetre.
    assert len(table) > 30_000
    assert np.abs(table[:, 2]).max() < 5e-4


def test_camera_pose_follows_the_pinhole_convention(ideal_frame: object, layout: CellLayout) -> None:
    T = ideal_frame.world_from_camera  # type: ignore[attr-defined]
    np.testing.assert_allclose(T, layout.camera.world_from_camera(), atol=1e-6)
    assert T[2, 2] == pytest.approx(-math.sin(math.radians(55.0)), abs=1e-6)  # looks down along +z
    assert T[2, 1] < 0  # image y points down


def test_mug_top_is_seen_at_its_height(ideal_frame: object) -> None:
    frame = ideal_frame
    K = frame.intrinsics  # type: ignore[attr-defined]
    T = frame.world_from_camera  # type: ignore[attr-defined]
    camera_from_world = np.linalg.inv(T)
    # The closed bottom of the upside-down big mug faces the camera at the mug's height.
    h = BIG_MUG.height_mm / 1000
    p = camera_from_world @ np.array([0.05, -0.30, h, 1.0])
    u, v = round(K.fx * p[0] / p[2] + K.cx), round(K.fy * p[1] / p[2] + K.cy)
    ray = T[:3, :3] @ np.array([(u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0])  # world direction per unit depth
    expected_depth = (h - T[2, 3]) / ray[2]
    assert frame.depth_m[v, u] == pytest.approx(expected_depth, abs=5e-4)  # type: ignore[attr-defined]


def test_noise_sigma_grows_with_the_square_of_depth() -> None:
    noise = DepthNoise(disparity_step_px=0.0, random_dropout=0.0, edge_dropout=0.0)
    rng = np.random.default_rng(7)
    near = noise.apply(np.full((200, 200), 1.0, np.float32), rng)
    far = noise.apply(np.full((200, 200), 2.0, np.float32), rng)
    assert near.std() == pytest.approx(0.0015, rel=0.05)
    assert far.std() / near.std() == pytest.approx(4.0, rel=0.08)


def test_noise_quantises_depth_to_disparity_steps() -> None:
    noise = DepthNoise(sigma_at_1m_m=0.0, random_dropout=0.0, edge_dropout=0.0)
    depth = np.linspace(1.5, 1.6, 1000, dtype=np.float32).reshape(10, 100)
    out = noise.apply(depth, np.random.default_rng(0)).astype(np.float64)
    disparity = noise.focal_px * noise.baseline_m / out
    steps = disparity / noise.disparity_step_px
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)
    assert len(np.unique(out)) == pytest.approx(0.1 * 580 * 0.075 / (1.55**2) / 0.125, abs=2)


def test_noise_loses_readings_out_of_range_and_behind_edges() -> None:
    noise = DepthNoise(sigma_at_1m_m=0.0, disparity_step_px=0.0, random_dropout=0.0, edge_dropout=1.0)
    depth = np.full((4, 6), 1.0, np.float32)
    depth[:, 3:] = 1.5  # a step: the far side's first column is shadowed
    depth[0, 0] = 4.5  # beyond the sensor's range
    out = noise.apply(depth, np.random.default_rng(0))
    assert out[0, 0] == 0.0
    assert (out[:, 3] == 0.0).all()
    np.testing.assert_allclose(out[1:, :3], 1.0, atol=1e-6)
    np.testing.assert_allclose(out[:, 4:], 1.5, atol=1e-6)


def test_negative_noise_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match=r"DepthNoise.sigma_at_1m_m must not be negative, got -0.1"):
        DepthNoise(sigma_at_1m_m=-0.1)


def test_camera_refuses_an_unknown_camera_name(world: tuple[object, object]) -> None:
    model, data = world
    with pytest.raises(ValueError, match=r"the model has no camera named 'kinect'; add it to the MJCF"):
        DepthCamera(model, data, camera_name="kinect")


def test_closed_camera_refuses_to_render(world: tuple[object, object]) -> None:
    model, data = world
    cam = DepthCamera(model, data, width=64, height=48)
    with cam:
        assert cam.render().depth_m.shape == (48, 64)
    with pytest.raises(RuntimeError, match=r"camera 'depth_camera' is closed"):
        cam.render()
