"""The thesis arm as a URDF, generated from Table 3.1 (modified DH), the servo models and bracket estimates.

Run ``python -m description.arm [OUT]`` to rewrite ``description/thesis_arm.urdf``; a test keeps the
committed file equal to what this module generates, so edit the data here, never the URDF by hand.

Each row of Table 3.1 is read as Rx(alpha)·Tx(a)·Rz(theta)·Tz(d) (Craig). The URDF joint origin is then
Rx(alpha)·Tx(a)·Tz(d) with the joint turning about its local z axis. Two additions the table does not give:
the arm's base stands ``base_height_m`` above the counter (the shoulder-turn servo and its horn), and the
gripper's finger hinges about the axis normal to the grasp plane at the palm (the table's last row only
places the gripper frame; a hinge along the approach axis could not close a finger on a mug). The grasp
point sits on the approach axis a finger length beyond the palm, level with the mug axis in a side grasp.

Link masses and inertias are the sums of the servos a link carries (``SERVO_MODELS``) and estimated
aluminium brackets, each a solid box.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final
from xml.etree import ElementTree as ET

import numpy as np

from description import thesis
from description.servos import SERVO_MODELS

BUNDLED_URDF: Final = Path(__file__).with_name("thesis_arm.urdf")
GRASP_FRAME: Final = "grasp_point"


@dataclass(frozen=True, slots=True)
class Part:
    """A solid box of a link: mass, size along the link frame's x, y, z, and its centre in that frame."""

    mass_kg: float
    size_m: tuple[float, float, float]
    center_m: tuple[float, float, float]


def finger_length_from_payload_reach() -> float:
    """The finger length that puts a held mug's axis at the rated payload reach (§3.2.1) when the arm is
    stretched out horizontally: 0.728 m minus the upper arm, forearm and wrist-to-palm lengths."""
    rows = {r.joint: r for r in thesis.DH_TABLE}
    stretched = rows["elbow_lift"].a_m + rows["wrist_lift"].a_m + rows["wrist_turn"].d_m + rows["gripper"].d_m
    return thesis.ARM_PAYLOAD_REACH_M - stretched


@dataclass(frozen=True, slots=True)
class GripperGeometry:
    """The fixed thumb and hinged finger of the gripper, in the grasp frame (z = approach, y = closing side).

    The mug's axis sits ``(r - thumb_width_m)`` along +y of the grasp point when held upright (thumb face at
    y = -thumb_width_m), which is the thesis's Eq 4.30 geometry with finger length l_g and thumb width w_g.
    The finger's tip is ``hinge_offset_m`` along +y at joint angle 0 and swings towards the thumb as the
    angle grows: aperture = hinge_offset + thumb_width - finger_length * sin(angle).
    """

    finger_length_m: float = field(default_factory=finger_length_from_payload_reach)
    thumb_width_m: float = 0.02
    hinge_offset_m: float = 0.07
    plate_thickness_m: float = 0.004  # thumb and finger: bent aluminium plate with its pad

    def aperture_m(self, angle_rad: float) -> float:
        """Distance between the thumb face and the finger tip at a gripper joint angle."""
        return self.hinge_offset_m + self.thumb_width_m - self.finger_length_m * math.sin(angle_rad)

    def angle_for_aperture(self, aperture_m: float) -> float:
        """The gripper joint angle giving an aperture; raises ValueError outside the finger's swing."""
        s = (self.hinge_offset_m + self.thumb_width_m - aperture_m) / self.finger_length_m
        if not -1.0 <= s <= 1.0:
            raise ValueError(f"aperture_m={aperture_m:.4f} is outside what the finger can reach")
        return math.asin(s)


@dataclass(frozen=True, slots=True)
class JointLimit:
    lower_rad: float
    upper_rad: float


# Mechanical limits of the brackets (estimates: the MX servos turn a full circle in joint mode, the AX-12A
# 300°). Shoulder lift 0 is the upper arm pointing forward, negative raises it; the elbow folds down with
# positive angles; the wrist turn is the AX-12A's whole travel (-150° to 149.7°), which keeps the upright
# (-pi/2) and upside-down (+pi/2) side grasps in range.
JOINT_LIMITS: Final[dict[str, JointLimit]] = {
    "shoulder_turn": JointLimit(-2.8, 2.8),
    "shoulder_lift": JointLimit(-2.0, 0.3),
    "elbow_lift": JointLimit(-1.0, 2.8),
    "wrist_lift": JointLimit(-2.8, 2.8),
    "wrist_turn": JointLimit(*SERVO_MODELS["AX-12A"].travel_rad),
    "gripper": JointLimit(-0.35, 1.5),
}


@dataclass(frozen=True, slots=True)
class ArmDescription:
    """Everything the generated URDF is made of."""

    name: str = "dishbot_thesis_arm"
    base_height_m: float = 0.05
    gripper: GripperGeometry = field(default_factory=GripperGeometry)
    joint_limits: dict[str, JointLimit] = field(default_factory=lambda: dict(JOINT_LIMITS))


def _servo_part(servo: str, center: tuple[float, float, float], *, long_axis: int = 1) -> Part:
    model = SERVO_MODELS[servo]
    w, h, d = model.size_m
    size = [w, d, w]
    size[long_axis] = h
    return Part(model.mass_kg, (size[0], size[1], size[2]), center)


def link_parts(desc: ArmDescription) -> dict[str, list[Part]]:
    """The boxes each moving link is made of, in its own (DH) frame."""
    rows = {r.joint: r for r in thesis.DH_TABLE}
    servos = dict(thesis.JOINT_SERVOS)
    upper = rows["elbow_lift"].a_m
    fore = rows["wrist_lift"].a_m
    wrist = rows["wrist_turn"].d_m
    palm = rows["gripper"].d_m
    g = desc.gripper
    t = g.plate_thickness_m
    palm_width = g.thumb_width_m + g.hinge_offset_m + 2 * t
    palm_center_x = (g.thumb_width_m - g.hinge_offset_m) / 2
    return {
        "base_link": [_servo_part(servos["shoulder_turn"], (0.0, 0.0, -0.02), long_axis=2)],
        # The shoulder-lift servo and its U bracket turn with the shoulder.
        "turret_link": [
            _servo_part(servos["shoulder_lift"], (0.0, 0.0, 0.0), long_axis=2),
            Part(0.045, (0.05, 0.05, 0.04), (0.0, 0.0, -0.005)),
        ],
        # Twin side plates of the upper arm, with the elbow servo at its far end.
        "upper_arm_link": [
            Part(0.110, (upper, 0.045, 0.03), (upper / 2, 0.0, 0.0)),
            _servo_part(servos["elbow_lift"], (upper, 0.0, 0.0), long_axis=2),
        ],
        "forearm_link": [
            Part(0.080, (fore, 0.04, 0.03), (fore / 2, 0.0, 0.0)),
            _servo_part(servos["wrist_lift"], (fore, 0.0, 0.0), long_axis=2),
        ],
        # The wrist-turn servo lies along the wrist link, which runs along y of the wrist-lift frame.
        "wrist_link": [
            _servo_part(servos["wrist_turn"], (0.0, wrist / 2, 0.0), long_axis=1),
            Part(0.020, (0.04, wrist, 0.03), (0.0, wrist / 2, 0.0)),
        ],
        # Gripper servo behind the palm plate (its whole length: a servo reaching past the plate would push
        # a mug out of the grasp), palm plate, and the fixed thumb (grasp y = -x of this frame).
        "gripper_link": [
            _servo_part(
                servos["gripper"],
                (0.0, 0.0, palm - t / 2 - SERVO_MODELS[servos["gripper"]].size_m[1] / 2),
                long_axis=2,
            ),
            # The palm plate spans from the thumb to the finger hinge (grasp y from -thumb to +hinge).
            Part(0.020, (palm_width, 0.04, 0.004), (palm_center_x, 0.0, palm)),
            Part(
                0.015,
                (t, 0.03, g.finger_length_m),
                (g.thumb_width_m + t / 2, 0.0, palm + g.finger_length_m / 2),
            ),
        ],
        "finger_link": [Part(0.015, (t, 0.03, g.finger_length_m), (-t / 2, 0.0, g.finger_length_m / 2))],
    }


def combined_inertia(parts: Sequence[Part]) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass and rotational inertia about the centre of mass of a set of solid boxes."""
    mass = sum(p.mass_kg for p in parts)
    com = sum((p.mass_kg * np.asarray(p.center_m) for p in parts), np.zeros(3)) / mass
    inertia = np.zeros((3, 3))
    for p in parts:
        x, y, z = p.size_m
        box = p.mass_kg / 12.0 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])
        r = np.asarray(p.center_m) - com
        inertia += box + p.mass_kg * (float(r @ r) * np.eye(3) - np.outer(r, r))
    return mass, com, inertia


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{v:.9g}" if abs(v) > 1e-15 else "0" for v in values)


def _link(robot: ET.Element, name: str, parts: Sequence[Part] | None) -> None:
    link = ET.SubElement(robot, "link", name=name)
    if not parts:
        return
    mass, com, inertia = combined_inertia(parts)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz=_fmt([float(v) for v in com]), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{mass:.6g}")
    ET.SubElement(
        inertial,
        "inertia",
        ixx=f"{inertia[0, 0]:.6g}",
        ixy=f"{inertia[0, 1]:.6g}",
        ixz=f"{inertia[0, 2]:.6g}",
        iyy=f"{inertia[1, 1]:.6g}",
        iyz=f"{inertia[1, 2]:.6g}",
        izz=f"{inertia[2, 2]:.6g}",
    )
    for tag in ("visual", "collision"):
        for p in parts:
            el = ET.SubElement(link, tag)
            ET.SubElement(el, "origin", xyz=_fmt(p.center_m), rpy="0 0 0")
            geom = ET.SubElement(el, "geometry")
            ET.SubElement(geom, "box", size=_fmt(p.size_m))


def _joint(
    robot: ET.Element,
    name: str,
    kind: str,
    parent: str,
    child: str,
    xyz: Sequence[float],
    rpy: Sequence[float],
    *,
    axis: Sequence[float] = (0.0, 0.0, 1.0),
    limit: JointLimit | None = None,
    servo: str | None = None,
) -> None:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=_fmt(xyz), rpy=_fmt(rpy))
    if kind == "fixed":
        return
    ET.SubElement(joint, "axis", xyz=_fmt(axis))
    if limit is None or servo is None:
        raise ValueError(f"joint {name!r} needs a limit and a servo")
    model = SERVO_MODELS[servo]
    ET.SubElement(
        joint,
        "limit",
        lower=f"{limit.lower_rad:.9g}",
        upper=f"{limit.upper_rad:.9g}",
        effort=f"{model.stall_torque_nm:.6g}",
        velocity=f"{model.no_load_speed_rad_s:.6g}",
    )
    ET.SubElement(joint, "dynamics", damping="0.1", friction="0.0")


def dh_origin(
    a_m: float, d_m: float, alpha_rad: float
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """URDF origin (xyz, rpy) of a modified-DH row: Rx(alpha)·Tx(a)·Tz(d), the joint turning about z."""
    xyz = (a_m, -d_m * math.sin(alpha_rad), d_m * math.cos(alpha_rad))
    return xyz, (alpha_rad, 0.0, 0.0)


def build_urdf(desc: ArmDescription | None = None) -> str:
    """The URDF text of the thesis arm: world -> base -> five arm joints -> gripper, plus the grasp frame."""
    desc = desc or ArmDescription()
    parts = link_parts(desc)
    servos = dict(thesis.JOINT_SERVOS)
    robot = ET.Element("robot", name=desc.name)
    robot.append(ET.Comment(" Generated by description/arm.py from Table 3.1 of the thesis; do not edit. "))
    chain = [
        ("shoulder_turn", "base_link", "turret_link"),
        ("shoulder_lift", "turret_link", "upper_arm_link"),
        ("elbow_lift", "upper_arm_link", "forearm_link"),
        ("wrist_lift", "forearm_link", "wrist_link"),
        ("wrist_turn", "wrist_link", "gripper_link"),
    ]
    _link(robot, "world", None)
    _link(robot, "base_link", parts["base_link"])
    _joint(
        robot, "base_mount", "fixed", "world", "base_link", (0.0, 0.0, desc.base_height_m), (0.0, 0.0, 0.0)
    )
    rows = {r.joint: r for r in thesis.DH_TABLE}
    for joint, parent, child in chain:
        row = rows[joint]
        _link(robot, child, parts[child])
        xyz, rpy = dh_origin(row.a_m, row.d_m, row.alpha_rad)
        _joint(
            robot,
            joint,
            "revolute",
            parent,
            child,
            xyz,
            rpy,
            limit=desc.joint_limits[joint],
            servo=servos[joint],
        )
    g = desc.gripper
    grip = rows["gripper"]
    palm_xyz, _ = dh_origin(grip.a_m, grip.d_m, grip.alpha_rad)
    _link(robot, "finger_link", parts["finger_link"])
    # The finger hinge sits at the palm, hinge_offset along the grasp frame's +y (= -x of gripper_link),
    # turning about the grasp frame's x (= +y of gripper_link) so that positive angles close the gripper.
    _joint(
        robot,
        "gripper",
        "revolute",
        "gripper_link",
        "finger_link",
        (palm_xyz[0] - g.hinge_offset_m, palm_xyz[1], palm_xyz[2]),
        (0.0, 0.0, 0.0),
        axis=(0.0, 1.0, 0.0),
        limit=desc.joint_limits["gripper"],
        servo=servos["gripper"],
    )
    _link(robot, GRASP_FRAME, None)
    _joint(
        robot,
        f"{GRASP_FRAME}_mount",
        "fixed",
        "gripper_link",
        GRASP_FRAME,
        (palm_xyz[0], palm_xyz[1], palm_xyz[2] + g.finger_length_m),
        (0.0, 0.0, math.pi / 2),
    )
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Write the bundled URDF (or the path given as the only argument)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) > 1 or (args and args[0].startswith("-")):
        print(
            "usage: python -m description.arm [OUT.urdf]  (default: the bundled URDF)",
            file=sys.stderr,
        )
        return 2
    out = Path(args[0]) if args else BUNDLED_URDF
    out.write_text(build_urdf(), encoding="utf-8")
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
