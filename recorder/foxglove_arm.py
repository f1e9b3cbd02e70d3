"""The arm's frames for the Foxglove views: the URDF's kinematic tree, read once, and a small chain for poses.

Each URDF joint places its child link in its parent's frame: the joint origin, then the joint's motion about
(or along) its axis. The Foxglove 3D panel composes the tree itself from one ``FrameTransform`` per joint,
so the recorder only needs each joint's local transform at the current joint angles (``local_transforms``);
``world_from`` composes the chain where the daemon needs a link's pose itself (a carried mug follows the
gripper). Each link's visual boxes and cylinders are what the 3D panel draws for the arm.

Plain Python and numpy: this runs for every joint sample on the recorder's thread, where loading Pinocchio's
model would be too heavy for what it would add (the planner's ``ArmModel`` computes the same poses; a test
compares the two).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final
from xml.etree import ElementTree as ET

import numpy as np
import numpy.typing as npt

from description.arm import BUNDLED_URDF

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # x, y, z, w
Matrix = npt.NDArray[np.float64]

IDENTITY: Final[Quat] = (0.0, 0.0, 0.0, 1.0)
_MOVING = ("revolute", "continuous", "prismatic")
_KINDS = (*_MOVING, "fixed")


@dataclass(frozen=True, slots=True)
class FrameTransform:
    """The child frame's origin and orientation in the parent frame."""

    parent: str
    child: str
    translation: Vec3
    rotation: Quat


@dataclass(frozen=True, slots=True)
class Joint:
    """One URDF joint: the child's origin in the parent at joint position 0, and its axis."""

    name: str
    kind: str
    parent: str
    child: str
    origin_xyz: Vec3
    origin_rotation: Quat
    axis: Vec3


@dataclass(frozen=True, slots=True)
class Visual:
    """A box, cylinder or sphere of a link's visual geometry, in the link's frame.

    ``size`` is the extent along the shape's x, y, z: a cylinder is (2r, 2r, length) along its z axis."""

    link: str
    shape: str
    size: Vec3
    xyz: Vec3
    rotation: Quat


class UrdfError(ValueError):
    """The arm's URDF cannot be read as a tree of joints; the message names the file and the element."""


@dataclass(frozen=True, slots=True)
class ArmFrames:
    """The kinematic tree of a URDF (joints parents first) and the visual shapes of its links."""

    root: str
    joints: tuple[Joint, ...]
    visuals: tuple[Visual, ...]

    @classmethod
    def load(cls, path: Path = BUNDLED_URDF) -> ArmFrames:
        """Read a URDF; ``UrdfError`` (one line) when it is unreadable or not a single tree."""
        try:
            robot = ET.parse(path).getroot()
        except (OSError, ET.ParseError) as e:
            raise UrdfError(f"cannot read the arm description {path}: {e}") from e
        joints = [_joint(element, path) for element in robot.findall("joint")]
        children = {j.child for j in joints}
        links = [str(link.get("name", "")) for link in robot.findall("link")]
        roots = [name for name in links if name not in children]
        if len(roots) != 1:
            raise UrdfError(f"{path}: expected one root link, found {roots or 'none'}")
        ordered = _parents_first(roots[0], joints, path)
        visuals = tuple(v for link in robot.findall("link") for v in _visuals(link, path))
        return cls(roots[0], ordered, visuals)

    @property
    def frames(self) -> tuple[str, ...]:
        """Every link frame, the root first."""
        return (self.root, *(j.child for j in self.joints))

    def local_transforms(self, positions: Mapping[str, float]) -> list[FrameTransform]:
        """One transform per joint at the given joint positions (a joint not given stands at 0)."""
        out = []
        for joint in self.joints:
            q = positions.get(joint.name, 0.0) if joint.kind in _MOVING else 0.0
            out.append(_local(joint, q))
        return out

    def world_from(self, frame: str, positions: Mapping[str, float]) -> Matrix:
        """The 4×4 pose of a link frame in the root frame at the given joint positions."""
        by_child = {t.child: t for t in self.local_transforms(positions)}
        pose = np.eye(4)
        while frame != self.root:
            transform = by_child.get(frame)
            if transform is None:
                raise KeyError(frame)
            pose = matrix(transform.translation, transform.rotation) @ pose
            frame = transform.parent
        return pose


def _local(joint: Joint, q: float) -> FrameTransform:
    rotation = joint.origin_rotation
    xyz = joint.origin_xyz
    if joint.kind == "prismatic":
        ax = rotate(rotation, joint.axis)
        xyz = (xyz[0] + ax[0] * q, xyz[1] + ax[1] * q, xyz[2] + ax[2] * q)
    elif joint.kind != "fixed" and q != 0.0:
        rotation = multiply(rotation, axis_angle(joint.axis, q))
    return FrameTransform(joint.parent, joint.child, xyz, rotation)


def _parents_first(root: str, joints: Sequence[Joint], path: Path) -> tuple[Joint, ...]:
    ordered: list[Joint] = []
    reached = {root}
    pending = list(joints)
    while pending:
        ready = [j for j in pending if j.parent in reached]
        if not ready:
            raise UrdfError(f"{path}: joints {[j.name for j in pending]} do not hang from {root}")
        for j in ready:
            ordered.append(j)
            reached.add(j.child)
            pending.remove(j)
    return tuple(ordered)


def _joint(element: ET.Element, path: Path) -> Joint:
    name = element.get("name", "")
    kind = element.get("type", "")
    if kind not in _KINDS:
        raise UrdfError(f"{path}: joint {name!r} has type {kind!r}; supported: {', '.join(_KINDS)}")
    parent, child = element.find("parent"), element.find("child")
    if parent is None or child is None:
        raise UrdfError(f"{path}: joint {name!r} lacks its parent or child link")
    xyz, rotation = _origin(element.find("origin"), path, f"joint {name!r}")
    axis_element = element.find("axis")
    axis = _floats(axis_element.get("xyz", "1 0 0") if axis_element is not None else "1 0 0", path, name)
    norm = math.sqrt(sum(a * a for a in axis))
    if kind != "fixed" and norm == 0.0:
        raise UrdfError(f"{path}: joint {name!r} has a zero axis")
    unit = (axis[0] / norm, axis[1] / norm, axis[2] / norm) if norm else (1.0, 0.0, 0.0)
    return Joint(name, kind, str(parent.get("link")), str(child.get("link")), xyz, rotation, unit)


def _visuals(link: ET.Element, path: Path) -> list[Visual]:
    name = str(link.get("name", ""))
    out = []
    for visual in link.findall("visual"):
        xyz, rotation = _origin(visual.find("origin"), path, f"link {name!r}")
        geometry = visual.find("geometry")
        shape = geometry[0] if geometry is not None and len(geometry) else None
        if shape is None:
            continue
        if shape.tag == "box":
            size = _floats(shape.get("size", ""), path, name)
        elif shape.tag in ("cylinder", "sphere"):
            r = float(shape.get("radius", "0"))
            length = float(shape.get("length", "0")) if shape.tag == "cylinder" else 2 * r
            size = (2 * r, 2 * r, length)
        else:
            continue  # meshes are not drawn: the bundled arm has none
        out.append(Visual(name, shape.tag, size, xyz, rotation))
    return out


def _origin(element: ET.Element | None, path: Path, where: str) -> tuple[Vec3, Quat]:
    if element is None:
        return (0.0, 0.0, 0.0), IDENTITY
    xyz = _floats(element.get("xyz", "0 0 0"), path, where)
    rpy = _floats(element.get("rpy", "0 0 0"), path, where)
    return xyz, from_rpy(*rpy)


def _floats(text: str, path: Path, where: str) -> Vec3:
    try:
        values = [float(v) for v in text.split()]
    except ValueError as e:
        raise UrdfError(f"{path}: {where}: {text!r} is not three numbers") from e
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UrdfError(f"{path}: {where}: {text!r} is not three numbers")
    return values[0], values[1], values[2]


# --- quaternions (x, y, z, w) -------------------------------------------------------------------------------


def from_rpy(roll: float, pitch: float, yaw: float) -> Quat:
    """URDF's fixed-axis roll (x), pitch (y), yaw (z): R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    return multiply(
        axis_angle((0.0, 0.0, 1.0), yaw),
        multiply(axis_angle((0.0, 1.0, 0.0), pitch), axis_angle((1.0, 0.0, 0.0), roll)),
    )


def axis_angle(axis: Vec3, angle: float) -> Quat:
    s = math.sin(angle / 2.0)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2.0))


def multiply(a: Quat, b: Quat) -> Quat:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotate(q: Quat, v: Vec3) -> Vec3:
    x, y, z, _ = multiply(multiply(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return x, y, z


def matrix(translation: Vec3, rotation: Quat) -> Matrix:
    """A 4×4 homogeneous transform."""
    x, y, z, w = rotation
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, 3] = translation
    return T


def pose_of(T: Matrix) -> tuple[Vec3, Quat]:
    """Translation and unit quaternion of a 4×4 rigid transform."""
    R = T[:3, :3]
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = ((R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s)
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = (0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s)
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = ((R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = ((R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s)
    n = math.sqrt(sum(c * c for c in q))
    t = T[:3, 3]
    return (float(t[0]), float(t[1]), float(t[2])), (
        float(q[0] / n),
        float(q[1] / n),
        float(q[2] / n),
        float(q[3] / n),
    )
