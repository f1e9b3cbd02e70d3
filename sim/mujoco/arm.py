"""The physics arm: MJCF bodies, joints and servo actuators generated from the arm's URDF.

The planner's kinematic model (``planning.arm``) and this physics model read the same URDF
(``description/thesis_arm.urdf``), so the arm the planner reasons about is the arm the simulator moves.
Each revolute URDF joint becomes a MuJoCo hinge and ``fixed`` joints static attachments; every servo-driven
joint (``description.thesis.JOINT_SERVOS``, the gripper's finger hinge included) gets a position actuator
whose stiffness, torque limit and reflected rotor inertia follow the Dynamixel model that drives it (§3.2.1,
``description.servos``). The URDF's gripper is a fixed thumb on the gripper link and a hinged finger; the
physics adds the force-sensing resistor as a thin pad on the thumb's inner face (the thesis glued it to the
gripper's inner pad, Fig 3.4) and a rubber pad on the finger, both sized from the planner's
``GripperGeometry``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import mujoco
import numpy as np

from description.arm import BUNDLED_URDF, GRASP_FRAME, GripperGeometry
from description.servos import SERVO_MODELS, ServoModel
from description.thesis import JOINT_SERVOS
from sim.mujoco.errors import SimModelError

# Prefixes of every MJCF name the arm adds, so the world and the collision accounting find them.
ARM_PREFIX: Final = "arm/"
SERVO_PREFIX: Final = "servo/"
FSR_PAD_GEOM: Final = "gripper/fsr_pad"
FINGER_PAD_GEOM: Final = "gripper/finger_pad"
TCP_SITE: Final = "gripper/tcp"


@dataclass(frozen=True, slots=True)
class UrdfJoint:
    name: str
    type: str  # revolute, continuous, prismatic, fixed
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float
    upper: float
    effort: float
    velocity: float


@dataclass(frozen=True, slots=True)
class UrdfInertial:
    mass_kg: float
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    # ixx, iyy, izz, ixy, ixz, iyz
    inertia: tuple[float, float, float, float, float, float]


@dataclass(frozen=True, slots=True)
class UrdfGeom:
    kind: str  # box, cylinder, sphere
    size: tuple[float, ...]
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class UrdfLink:
    name: str
    inertial: UrdfInertial | None
    geoms: tuple[UrdfGeom, ...]


@dataclass(frozen=True, slots=True)
class UrdfModel:
    """The parts of a URDF the physics needs: the link tree, inertias, primitive collision shapes, limits."""

    name: str
    links: Mapping[str, UrdfLink]
    joints: tuple[UrdfJoint, ...]

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints}
        roots = [name for name in self.links if name not in children]
        if len(roots) != 1:
            raise SimModelError(f"URDF {self.name!r}: expected one root link, found {sorted(roots)}")
        return roots[0]

    def children_of(self, link: str) -> tuple[UrdfJoint, ...]:
        return tuple(j for j in self.joints if j.parent == link)


def _floats(text: str | None, n: int, default: float = 0.0) -> tuple[float, ...]:
    if text is None:
        return (default,) * n
    values = tuple(float(v) for v in text.split())
    if len(values) != n:
        raise SimModelError(f"URDF attribute {text!r}: expected {n} numbers")
    return values


def _origin(el: ET.Element | None) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    if el is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    xyz = _floats(el.get("xyz"), 3)
    rpy = _floats(el.get("rpy"), 3)
    return (xyz[0], xyz[1], xyz[2]), (rpy[0], rpy[1], rpy[2])


def _geom(el: ET.Element) -> UrdfGeom | None:
    xyz, rpy = _origin(el.find("origin"))
    shape = el.find("geometry")
    if shape is None or len(shape) == 0:
        return None
    prim = shape[0]
    if prim.tag == "box":
        return UrdfGeom("box", _floats(prim.get("size"), 3), xyz, rpy)
    if prim.tag == "cylinder":
        return UrdfGeom(
            "cylinder", (float(prim.get("radius", "0")), float(prim.get("length", "0"))), xyz, rpy
        )
    if prim.tag == "sphere":
        return UrdfGeom("sphere", (float(prim.get("radius", "0")),), xyz, rpy)
    return None  # meshes: the physics uses primitives only


def parse_urdf(text: str, *, source: str = "<string>") -> UrdfModel:
    """Read the link tree of a URDF document. Raises ``SimModelError`` naming ``source`` when malformed."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise SimModelError(f"URDF {source}: not well-formed XML ({e}); fix the file") from e
    if root.tag != "robot":
        raise SimModelError(f"URDF {source}: root element is <{root.tag}>, expected <robot>")
    links: dict[str, UrdfLink] = {}
    for el in root.findall("link"):
        inertial = None
        iel = el.find("inertial")
        if iel is not None:
            xyz, rpy = _origin(iel.find("origin"))
            mass_el = iel.find("mass")
            inertia_el = iel.find("inertia")
            mass = float(mass_el.get("value", "0")) if mass_el is not None else 0.0
            i = [0.0] * 6
            if inertia_el is not None:
                i = [float(inertia_el.get(k, "0")) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
            inertial = UrdfInertial(mass, xyz, rpy, (i[0], i[1], i[2], i[3], i[4], i[5]))
        shapes = [g for g in (_geom(c) for c in el.findall("collision")) if g is not None]
        name = el.get("name", "")
        links[name] = UrdfLink(name, inertial, tuple(shapes))
    joints = []
    for el in root.findall("joint"):
        name = el.get("name", "")
        parent, child = el.find("parent"), el.find("child")
        if parent is None or child is None:
            raise SimModelError(f"URDF {source}: joint {name!r} lacks <parent> or <child>")
        xyz, rpy = _origin(el.find("origin"))
        axis = _floats(el.find("axis").get("xyz") if el.find("axis") is not None else None, 3, 0.0)  # type: ignore[union-attr]
        if not any(axis):
            axis = (1.0, 0.0, 0.0)
        limit = el.find("limit")
        lower = float(limit.get("lower", "-3.14159")) if limit is not None else -math.pi
        upper = float(limit.get("upper", "3.14159")) if limit is not None else math.pi
        effort = float(limit.get("effort", "0")) if limit is not None else 0.0
        velocity = float(limit.get("velocity", "0")) if limit is not None else 0.0
        joints.append(
            UrdfJoint(
                name,
                el.get("type", "fixed"),
                parent.get("link", ""),
                child.get("link", ""),
                xyz,
                rpy,
                (axis[0], axis[1], axis[2]),
                lower,
                upper,
                effort,
                velocity,
            )
        )
    model = UrdfModel(root.get("name", source), links, tuple(joints))
    for j in model.joints:
        for link in (j.parent, j.child):
            if link not in links:
                raise SimModelError(f"URDF {source}: joint {j.name!r} names unknown link {link!r}")
    _ = model.root
    return model


def load_urdf(path: Path) -> UrdfModel:
    try:
        text = path.read_text()
    except OSError as e:
        raise SimModelError(f"URDF {path}: cannot read ({e.strerror}); check the arm model path") from e
    return parse_urdf(text, source=str(path))


def rpy_to_quat(rpy: Sequence[float]) -> tuple[float, float, float, float]:
    """URDF fixed-axis roll-pitch-yaw to a MuJoCo (w, x, y, z) quaternion."""
    r, p, y = (float(v) / 2.0 for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _vec(v: Sequence[float]) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


# Rotor inertia reflected through each gear train (kg·m² at the output shaft: rotor inertia × ratio²). It
# dominates the link inertia of a small arm and keeps the joints stiff-but-stable at a 2 ms step.
ARMATURE_KG_M2: Final[Mapping[str, float]] = {
    "MX-106T": 0.030,
    "MX-64T": 0.020,
    "MX-28T": 0.008,
    "AX-12A": 0.004,
}
# Position error at which each servo's default controller delivers its stall torque: the MX series' PID
# (P gain 32) is stiff, the AX-12A's compliance slope (32) spreads its torque over several degrees.
FULL_TORQUE_ERROR_RAD: Final[Mapping[str, float]] = {
    "MX-106T": math.radians(2.0),
    "MX-64T": math.radians(2.0),
    "MX-28T": math.radians(2.0),
    "AX-12A": math.radians(6.0),
}
# Static friction of the spur gear trains (200:1 and more) as a fraction of the stall torque: a servo
# that stops keeps part of the squeeze or load it had, yet an arm with its torque off still sags, as real
# ones do (an estimate; the datasheets give no backdrive torque).
GEAR_FRICTION_FRACTION: Final = 0.10
# The FSR (a Pololu/Interlink 406 is about 0.5 mm thick) and the finger's rubber stand this far proud of the
# thumb and finger faces; the pads' boxes reach as far into the faces again.
PAD_THICKNESS_M: Final = 0.0005

# Arm geoms collide with the world and the mugs (contype 1 there) but not with each other.
_ARM_GEOM_ATTRS: Final = 'contype="2" conaffinity="1" friction="0.6 0.005 0.0001" rgba="0.25 0.27 0.3 1"'
# Rubber-faced pads: MuJoCo's default contact time constant with a wider impedance ramp, so a squeeze
# compresses them by a fraction of a millimetre rather than not at all.
_PAD_GEOM_ATTRS: Final = (
    'contype="2" conaffinity="1" condim="4" friction="1.0 0.01 0.001" solref="0.02 1" '
    'solimp="0.9 0.95 0.005" rgba="0.75 0.2 0.1 1" mass="0.001"'
)


@dataclass(frozen=True, slots=True)
class ArmServo:
    """One servo-driven joint of the physics arm: bus id, joint, model and joint limits."""

    servo_id: int
    joint: str
    model: ServoModel
    lower_rad: float
    upper_rad: float

    @property
    def mj_joint(self) -> str:
        return ARM_PREFIX + self.joint

    @property
    def mj_actuator(self) -> str:
        return SERVO_PREFIX + self.joint

    @property
    def armature_kg_m2(self) -> float:
        return ARMATURE_KG_M2[self.model.name]

    @property
    def stiffness_nm_per_rad(self) -> float:
        return self.model.stall_torque_nm / FULL_TORQUE_ERROR_RAD[self.model.name]


@dataclass(frozen=True, slots=True)
class ArmMjcf:
    """The arm as MJCF fragments for ``sim.mujoco.scene.build_mjcf`` plus what the world needs."""

    body_xml: str
    actuator_xml: str
    servos: tuple[ArmServo, ...]
    gripper: GripperGeometry
    tool_body: str  # the body carrying the thumb and the force pad; held mugs weld to it

    def servo(self, servo_id: int) -> ArmServo:
        for s in self.servos:
            if s.servo_id == servo_id:
                return s
        raise KeyError(f"no servo with id {servo_id} on the arm (ids: {[s.servo_id for s in self.servos]})")


def _inertial_xml(inertial: UrdfInertial | None, *, moving: bool) -> str:
    if inertial is None or inertial.mass_kg <= 0.0:
        # MuJoCo needs mass on every moving body; a massless moving URDF link gets a token 10 g.
        return '<inertial pos="0 0 0" mass="0.01" diaginertia="1e-6 1e-6 1e-6"/>' if moving else ""
    ixx, iyy, izz, ixy, ixz, iyz = inertial.inertia
    tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    # URDF gives the tensor in a frame turned by rpy from the link; MJCF's fullinertia is in the link frame.
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(rpy_to_quat(inertial.rpy)))
    r = rot.reshape(3, 3)
    t = r @ tensor @ r.T
    diag = [max(float(t[k, k]), 1e-7) for k in range(3)]
    full = (*diag, float(t[0, 1]), float(t[0, 2]), float(t[1, 2]))
    return f'<inertial pos="{_vec(inertial.xyz)}" mass="{inertial.mass_kg:.6g}" fullinertia="{_vec(full)}"/>'


def _geom_xml(link: str, n: int, g: UrdfGeom) -> str:
    pose = f'pos="{_vec(g.xyz)}" quat="{_vec(rpy_to_quat(g.rpy))}"'
    common = f'name="{ARM_PREFIX}{link}/{n}" {_ARM_GEOM_ATTRS} {pose}'
    if g.kind == "box":
        return f'<geom {common} type="box" size="{_vec([v / 2.0 for v in g.size])}" mass="0"/>'
    if g.kind == "cylinder":
        return f'<geom {common} type="cylinder" size="{g.size[0]:.6g} {g.size[1] / 2.0:.6g}" mass="0"/>'
    return f'<geom {common} type="sphere" size="{g.size[0]:.6g}" mass="0"/>'


def _thumb_pad_xml(grasp_xyz: Sequence[float], g: GripperGeometry) -> str:
    """The FSR on the thumb's inner face, in the tool link's frame (grasp +y is the tool link's -x)."""
    gx, gy, gz = grasp_xyz
    face_x = gx + g.thumb_width_m
    half_len = g.finger_length_m / 2.0
    return (
        f'<geom name="{FSR_PAD_GEOM}" type="box" {_PAD_GEOM_ATTRS} '
        f'size="{PAD_THICKNESS_M:.6g} 0.015 {half_len - 0.002:.6g}" '
        f'pos="{face_x:.6g} {gy:.6g} {gz - half_len:.6g}"/>'
    )


def _finger_pad_xml(g: GripperGeometry) -> str:
    """The rubber on the finger's inner face, in the finger link's frame (the face is its x = 0 plane)."""
    half_len = g.finger_length_m / 2.0
    return (
        f'<geom name="{FINGER_PAD_GEOM}" type="box" {_PAD_GEOM_ATTRS} '
        f'size="{PAD_THICKNESS_M:.6g} 0.015 {half_len - 0.002:.6g}" pos="0 0 {half_len:.6g}"/>'
    )


def build_arm_mjcf(
    urdf: UrdfModel,
    *,
    gripper: GripperGeometry | None = None,
    base_pos: Sequence[float] = (0.0, 0.0, 0.0),
    servo_ids: Mapping[str, int] | None = None,
) -> ArmMjcf:
    """The arm's MJCF: the URDF link tree with a hinge and a servo actuator per driven joint, and the pads.

    Joints named like the thesis's chain get the actuator of their servo model; ``servo_ids`` maps joint
    names to bus ids (default 1-6 in chain order). ``gripper`` must be the geometry the URDF was generated
    with (the planner's); the pads are placed on its thumb and finger faces.
    """
    g = gripper or GripperGeometry()
    ids = dict(servo_ids) if servo_ids is not None else {j: n + 1 for n, (j, _) in enumerate(JOINT_SERVOS)}
    models = dict(JOINT_SERVOS)
    finger = next((j for j in urdf.joints if j.name == "gripper"), None)
    grasp = next((j for j in urdf.joints if j.child == GRASP_FRAME), None)
    if finger is None or grasp is None:
        raise SimModelError(
            f"URDF {urdf.name!r}: needs a 'gripper' joint (the finger hinge) and a fixed joint to "
            f"{GRASP_FRAME!r}; regenerate it with python -m description.arm"
        )
    tool_link = finger.parent
    servos: list[ArmServo] = []

    def body(link: str, moving: bool, depth: int) -> str:
        if depth > 64:
            raise SimModelError(f"URDF {urdf.name!r}: link tree deeper than 64 at {link!r} (a cycle?)")
        parts = [_inertial_xml(urdf.links[link].inertial, moving=moving)]
        parts += [_geom_xml(link, n, geom) for n, geom in enumerate(urdf.links[link].geoms)]
        if link == tool_link:
            parts.append(_thumb_pad_xml(grasp.xyz, g))
        if link == finger.child:
            parts.append(_finger_pad_xml(g))
        if link == GRASP_FRAME:
            parts.append(f'<site name="{TCP_SITE}" size="0.004" rgba="0 1 0 0.5"/>')
        for j in urdf.children_of(link):
            head = (
                f'<body name="{ARM_PREFIX}{j.child}" pos="{_vec(j.xyz)}" quat="{_vec(rpy_to_quat(j.rpy))}">'
            )
            joint_xml = ""
            if j.type in ("revolute", "continuous"):
                if j.name not in models:
                    raise SimModelError(
                        f"URDF {urdf.name!r}: joint {j.name!r} has no servo; expected one of "
                        f"{', '.join(models)}"
                    )
                lower, upper = (j.lower, j.upper) if j.type == "revolute" else (-math.pi, math.pi)
                servo = ArmServo(ids[j.name], j.name, SERVO_MODELS[models[j.name]], lower, upper)
                servos.append(servo)
                joint_xml = (
                    f'<joint name="{servo.mj_joint}" type="hinge" axis="{_vec(j.axis)}" '
                    f'range="{lower:.6g} {upper:.6g}" armature="{servo.armature_kg_m2:.6g}" '
                    f'damping="{0.05 * servo.model.stall_torque_nm:.6g}" '
                    f'frictionloss="{GEAR_FRICTION_FRACTION * servo.model.stall_torque_nm:.6g}"/>'
                )
            elif j.type != "fixed":
                raise SimModelError(f"URDF {urdf.name!r}: {j.type} joint {j.name!r} is not part of this arm")
            parts.append(head + joint_xml + body(j.child, moving or bool(joint_xml), depth + 1) + "</body>")
        return "".join(parts)

    root = urdf.root
    body_xml = f'<body name="{ARM_PREFIX}{root}" pos="{_vec(base_pos)}">{body(root, False, 0)}</body>'
    missing = set(models) - {s.joint for s in servos}
    if missing:
        raise SimModelError(
            f"URDF {urdf.name!r}: no joint for {', '.join(sorted(missing))}; the arm needs all six"
        )
    servos.sort(key=lambda s: s.servo_id)
    return ArmMjcf(
        body_xml=body_xml,
        actuator_xml="".join(_actuator_xml(s) for s in servos),
        servos=tuple(servos),
        gripper=g,
        tool_body=ARM_PREFIX + tool_link,
    )


def _actuator_xml(s: ArmServo) -> str:
    """A position actuator standing in for the servo's internal P controller, torque-limited at stall, with
    near-critical damping for the rotor plus about as much link inertia again."""
    kp = s.stiffness_nm_per_rad
    kv = 2.0 * math.sqrt(kp * 2.0 * s.armature_kg_m2)
    torque = s.model.stall_torque_nm
    return (
        f'<position name="{s.mj_actuator}" joint="{s.mj_joint}" kp="{kp:.6g}" kv="{kv:.6g}" '
        f'ctrlrange="{s.lower_rad:.6g} {s.upper_rad:.6g}" forcerange="{-torque:.6g} {torque:.6g}"/>'
    )


def thesis_arm_mjcf(*, base_pos: Sequence[float] = (0.0, 0.0, 0.0)) -> ArmMjcf:
    """The thesis arm from the bundled URDF, with the planner's default gripper geometry."""
    return build_arm_mjcf(load_urdf(BUNDLED_URDF), base_pos=base_pos)
