"""The static simulated cell as MJCF: counter, tray, flip area, mugs with real shapes and the depth camera.

The world frame is the daemon's: origin on the arm's shoulder-turn axis at counter height (z = 0 is the
counter top), x forward, y to the robot's left, z up. ``build_mjcf`` returns one self-contained MJCF document;
the physical world (``sim.mujoco``'s arm and stepping) splices the arm in through the ``arm_*``
parameters. Every name is prefixed (``table/``, ``tray/``, ``flip_area``, ``mug/<id>/``) so contact accounting
can tell who touched whom.

A mug is an open cup: the rendered shell is a generated, watertight mesh (outer wall, rim, inner wall and
inner bottom), so the camera sees into an upright mug and sees a closed bottom on an upside-down one. Its
collision shape is a cylinder (hidden, geom group 3) plus the capsules of the handle, which are drawn as they
are.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from description.arrays import FloatArray
from description.camera import CameraSpec
from description.cell import CellLayout, SceneMug, Tray
from description.thesis import MugSpec

CAMERA_NAME: Final = "depth_camera"
TRAY_PREFIX: Final = "tray/"
TABLE_GEOM: Final = "table/top"
FLIP_AREA_GEOM: Final = "flip_area"
BOARD_GEOM: Final = "calibration/board"

# Shape of the generated mugs (not thesis figures: the thesis gives only the outer dimensions of §5.3).
MUG_WALL_M: Final = 0.004
MUG_BOTTOM_M: Final = 0.006
MUG_SEGMENTS: Final = 48
HANDLE_RADIUS_M: Final = 0.005
# Height of the handle's lower and upper arms as a fraction of the mug height; symmetric, so an upside-down
# mug keeps its handle at the same heights, well below the brim band the detector fits.
HANDLE_ARM_FRACTIONS: Final = (0.28, 0.72)


def build_mjcf(
    layout: CellLayout,
    mugs: Sequence[SceneMug],
    *,
    arm_body_xml: str = "",
    arm_actuator_xml: str = "",
    extra_assets: str = "",
    extra_body_xml: str = "",
    timestep_s: float = 0.002,
) -> str:
    """A complete MJCF document of the cell with these mugs (each on a free joint, at rest on its surface).

    ``arm_body_xml`` goes into the worldbody, ``arm_actuator_xml`` into ``<actuator>``, ``extra_assets`` into
    ``<asset>`` and ``extra_body_xml`` (e.g. a calibration board) into the worldbody.
    """
    ids = [m.mug_id for m in mugs]
    if len(set(ids)) != len(ids):
        raise ValueError(f"mug ids must be unique, got {sorted(ids)}")
    specs = {m.spec.name: m.spec for m in mugs}
    assets = "\n".join(_mug_mesh_asset(s) for s in specs.values())
    cam = layout.camera
    x0, y0, x1, y1 = layout.table_region_m
    table_h = layout.table_height_above_floor_m
    centre = ((x0 + x1) / 2, (y0 + y1) / 2, 0.0)
    bodies = "\n".join(_mug_body(m, layout.mug_base_z_m(m.x_m, m.y_m)) for m in mugs)
    fx, fy = layout.flip_area_center_m
    actuators = f"<actuator>\n{arm_actuator_xml}\n</actuator>" if arm_actuator_xml else ""
    return f"""<mujoco model="dishbot_cell">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep_s:.6g}" gravity="0 0 -9.81" cone="elliptic" impratio="10"/>
  <statistic extent="2.5" center="{_v(centre)}"/>
  <visual>
    <global offwidth="{max(cam.width, 640)}" offheight="{max(cam.height, 480)}"/>
    <map znear="0.02" zfar="4"/>
    <quality shadowsize="2048"/>
  </visual>
  <asset>
    <material name="table" rgba="0.72 0.62 0.50 1"/>
    <material name="tray" rgba="0.55 0.40 0.25 1"/>
    <material name="flip" rgba="0.25 0.55 0.30 1"/>
    <material name="floor" rgba="0.35 0.35 0.38 1"/>
    <material name="mug_big" rgba="0.85 0.20 0.15 1"/>
    <material name="mug_small" rgba="0.20 0.35 0.85 1"/>
    <material name="mug_other" rgba="0.85 0.85 0.80 1"/>
{assets}
{extra_assets}
  </asset>
  <worldbody>
    <light name="key" pos="{_v((centre[0], centre[1], 2.0))}" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>
    <geom name="floor" type="plane" pos="0 0 {-table_h:.6g}" size="5 5 0.1" material="floor"/>
    <geom name="{TABLE_GEOM}" type="box" pos="{_v((centre[0], centre[1], -table_h / 2))}"
          size="{_v(((x1 - x0) / 2, (y1 - y0) / 2, table_h / 2))}" material="table"
          friction="0.8 0.01 0.001"/>
    <geom name="{FLIP_AREA_GEOM}" type="cylinder" pos="{_v((fx, fy, 0.0005))}"
          size="{layout.flip_area_radius_m:.6g} 0.0005" material="flip" contype="0" conaffinity="0"/>
{_tray_xml(layout.tray)}
    {camera_mjcf(cam)}
{bodies}
{extra_body_xml}
{arm_body_xml}
  </worldbody>
  {actuators}
</mujoco>
"""


def calibration_board_xml(
    size_m: tuple[float, float], origin_xy: tuple[float, float], yaw_rad: float, *, texture_file: str
) -> tuple[str, str]:
    """(asset XML, body XML) of a printed calibration board lying face up on the table.

    ``texture_file`` names the board image, passed to ``MjModel.from_xml_string`` in its ``assets``; the
    image's top-left corner lies at ``origin_xy`` and its width runs along ``yaw_rad`` (the board frame of
    ``perception.calibration.board_on_table``). MuJoCo maps a plane's texture with the image's top-left at the
    plane's (-x, +y) corner.
    """
    w, h = size_m
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    centre = (origin_xy[0] + c * w / 2 + s * h / 2, origin_xy[1] + s * w / 2 - c * h / 2, 0.0004)
    assets = (
        f'    <texture name="calibration_board" type="2d" file="{texture_file}"/>\n'
        '    <material name="calibration_board" texture="calibration_board" texrepeat="1 1"/>'
    )
    body = (
        f'    <geom name="{BOARD_GEOM}" type="plane" pos="{_v(centre)}" euler="0 0 {yaw_rad:.6g}" '
        f'size="{w / 2:.6g} {h / 2:.6g} 0.01" material="calibration_board" contype="0" conaffinity="0"/>'
    )
    return assets, body


def mug_mesh(spec: MugSpec, *, segments: int = MUG_SEGMENTS) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """Vertices (n, 3) and outward-facing triangles (m, 3) of the open cup, origin at its bottom centre."""
    r_out = spec.diameter_mm / 2000.0
    r_in = r_out - MUG_WALL_M
    h = spec.height_mm / 1000.0
    a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    c, s = np.cos(a), np.sin(a)
    rings = [
        (r_out, 0.0),  # 0: outer bottom
        (r_out, h),  # 1: outer top
        (r_in, h),  # 2: inner top
        (r_in, MUG_BOTTOM_M),  # 3: inner bottom
    ]
    verts = [np.stack([r * c, r * s, np.full(segments, z)], axis=1) for r, z in rings]
    vertices = np.concatenate([*verts, [[0.0, 0.0, 0.0], [0.0, 0.0, MUG_BOTTOM_M]]])
    bottom_centre, inner_centre = 4 * segments, 4 * segments + 1
    faces: list[tuple[int, int, int]] = []
    for i in range(segments):
        j = (i + 1) % segments
        for ring in range(3):
            a0, a1 = ring * segments + i, ring * segments + j
            b0, b1 = (ring + 1) * segments + i, (ring + 1) * segments + j
            # Outer wall faces out, rim up, inner wall in: one winding serves all three ring pairs.
            faces.append((a0, a1, b1))
            faces.append((a0, b1, b0))
        faces.append((bottom_centre, j, i))  # outer bottom, facing down
        faces.append((inner_centre, 3 * segments + i, 3 * segments + j))  # inner bottom, facing up
    return vertices, np.asarray(faces, dtype=np.int64)


def _mug_mesh_asset(spec: MugSpec) -> str:
    vertices, faces = mug_mesh(spec)
    vtext = " ".join(f"{v:.6g}" for v in vertices.ravel())
    ftext = " ".join(str(int(f)) for f in faces.ravel())
    return f'    <mesh name="mug_shell_{spec.name}" vertex="{vtext}" face="{ftext}"/>'


def mug_inertia(spec: MugSpec) -> tuple[float, tuple[float, float, float]]:
    """Centre-of-mass height and principal moments of a cup: thin wall plus bottom disc (handle ignored)."""
    m = spec.mass_kg
    r = spec.diameter_mm / 2000.0
    h = spec.height_mm / 1000.0
    wall_area = 2 * math.pi * r * h
    disc_area = math.pi * r * r
    m_wall = m * wall_area / (wall_area + disc_area)
    m_disc = m - m_wall
    z_com = (m_wall * h / 2) / m
    izz = m_wall * r * r + m_disc * r * r / 2
    ixx = (
        m_wall * (r * r / 2 + h * h / 12)
        + m_wall * (h / 2 - z_com) ** 2
        + m_disc * r * r / 4
        + m_disc * z_com**2
    )
    return z_com, (ixx, ixx, izz)


def _mug_body(mug: SceneMug, base_z: float) -> str:
    spec = mug.spec
    r = spec.diameter_mm / 2000.0
    h = spec.height_mm / 1000.0
    reach = (spec.width_mm - spec.diameter_mm) / 1000.0  # how far the handle sticks out of the wall
    hr = HANDLE_RADIUS_M
    z_lo, z_hi = (f * h for f in HANDLE_ARM_FRACTIONS)
    x_out = r + reach - hr
    x_in = r - MUG_WALL_M / 2
    half = mug.yaw_rad / 2
    if mug.upside_down:
        quat = (0.0, math.cos(half), math.sin(half), 0.0)
        z = base_z + h
    else:
        quat = (math.cos(half), 0.0, 0.0, math.sin(half))
        z = base_z
    z_com, (ixx, iyy, izz) = mug_inertia(spec)
    material = f"mug_{spec.name}" if spec.name in ("big", "small") else "mug_other"
    n = mug.body_name
    return f"""    <body name="{n}" pos="{_v((mug.x_m, mug.y_m, z + 0.0002))}" quat="{_v(quat)}">
      <freejoint name="{n}/joint"/>
      <inertial pos="0 0 {z_com:.6g}" mass="{spec.mass_kg:.6g}" diaginertia="{_v((ixx, iyy, izz))}"/>
      <geom name="{n}/shell" type="mesh" mesh="mug_shell_{spec.name}" material="{material}"
            contype="0" conaffinity="0" group="1" mass="0"/>
      <geom name="{n}/body" type="cylinder" size="{r:.6g} {h / 2:.6g}" pos="0 0 {h / 2:.6g}" group="3"
            mass="0" friction="0.9 0.01 0.001"/>
      <geom name="{n}/handle_low" type="capsule" size="{hr:.6g}" material="{material}" mass="0"
            fromto="{_v((x_in, 0, z_lo))} {_v((x_out, 0, z_lo))}"/>
      <geom name="{n}/handle_high" type="capsule" size="{hr:.6g}" material="{material}" mass="0"
            fromto="{_v((x_in, 0, z_hi))} {_v((x_out, 0, z_hi))}"/>
      <geom name="{n}/handle_grip" type="capsule" size="{hr:.6g}" material="{material}" mass="0"
            fromto="{_v((x_out, 0, z_lo))} {_v((x_out, 0, z_hi))}"/>
    </body>"""


def _tray_xml(tray: Tray) -> str:
    x0, y0, x1, y1 = tray.region_m
    t, hw, base = tray.wall_thickness_m, tray.wall_height_m, tray.base_m
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    lx, ly = (x1 - x0) / 2, (y1 - y0) / 2
    walls = {
        "wall_near": ((x0 - t / 2, cy), (t / 2, ly + t)),
        "wall_far": ((x1 + t / 2, cy), (t / 2, ly + t)),
        "wall_right": ((cx, y0 - t / 2), (lx, t / 2)),
        "wall_left": ((cx, y1 + t / 2), (lx, t / 2)),
    }
    lines = [
        '    <body name="tray">',
        f'      <geom name="{TRAY_PREFIX}base" type="box" pos="{_v((cx, cy, base / 2))}" '
        f'size="{_v((lx, ly, base / 2))}" material="tray"/>',
    ]
    for name, ((px, py), (sx, sy)) in walls.items():
        lines.append(
            f'      <geom name="{TRAY_PREFIX}{name}" type="box" pos="{_v((px, py, hw / 2))}" '
            f'size="{_v((sx, sy, hw / 2))}" material="tray"/>'
        )
    lines.append("    </body>")
    return "\n".join(lines)


def _v(values: Sequence[float] | FloatArray) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


def camera_mjcf(camera: CameraSpec) -> str:
    """The ``<camera>`` element; MuJoCo cameras look along their -z with y up."""
    T = camera.world_from_camera()
    x_axis, up = T[:3, 0], -T[:3, 1]
    return (
        f'<camera name="{CAMERA_NAME}" mode="fixed" pos="{_v(camera.position_m)}" '
        f'xyaxes="{_v(x_axis)} {_v(up)}" fovy="{camera.fovy_deg:.6g}"/>'
    )
