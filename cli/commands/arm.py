"""``dishbot arm fk|ik|workspace|calibrate``: the arm model from the command line."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cli.commands.output import format_table
from daemon.config import load_config
from daemon.errors import ConfigError, UsageError

if TYPE_CHECKING:
    from planning.arm import ArmModel

# planning.arm.GraspKind's side grasps, spelled out so that building the parser loads no numpy
# (tests/daemon/test_cli_imports.py holds the two lists equal).
SIDE_GRASPS = ("side", "side-upside-down")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "arm",
        help="kinematics of the arm: forward, inverse, workspace, calibration",
        description=(
            "The arm model (the thesis arm's URDF built from its Table 3.1, or --urdf). Positions are the "
            "gripper's grasp point in the world frame: metres, origin on the shoulder-turn axis at counter "
            "height, x forward, y left, z up."
        ),
    )
    arm_sub = parser.add_subparsers(dest="arm_command", metavar="ACTION", required=True)

    fk = arm_sub.add_parser(
        "fk",
        help="where the grasp point is for five joint angles",
        description="Forward kinematics: the grasp point's position and rotation for five joint angles "
        "(shoulder turn, shoulder lift, elbow lift, wrist lift, wrist turn; radians).",
    )
    for i in range(1, 6):
        fk.add_argument(f"q{i}", metavar=f"Q{i}", help=f"joint {i} angle in radians")
    _common(fk)
    fk.set_defaults(handler=run_fk)

    ik = arm_sub.add_parser(
        "ik",
        help="joint angles that put the grasp point at X Y Z",
        description="Inverse kinematics. Without --grasp only the position is asked for; with it the gripper "
        "also approaches horizontally along the line from the shoulder axis (the arm has no wrist yaw), "
        "upright or turned upside down. Exits 1 when there is no solution.",
    )
    for name in ("x", "y", "z"):
        ik.add_argument(name, metavar=name.upper(), help=f"target {name} in metres")
    ik.add_argument(
        "--grasp",
        choices=SIDE_GRASPS,
        help="side grasp orientation (default: position only)",
    )
    _common(ik)
    ik.set_defaults(handler=run_ik)

    ws = arm_sub.add_parser(
        "workspace",
        help="where mugs can be picked and placed, and the tray the arm can serve",
        description="Reachability of the side grasps at the cycle's heights for every mug type, the largest "
        "tray centred on the arm's x axis it can serve, and whether the configured cell is reachable.",
    )
    ws.add_argument("--config", type=Path, metavar="FILE", help="config file whose [cell] to check and draw")
    ws.add_argument("--png", type=Path, metavar="FILE", help="also draw the regions and the cell as PNG")
    _common(ws)
    ws.set_defaults(handler=run_workspace)

    cal = arm_sub.add_parser(
        "calibrate",
        help="fit a position correction from measured (commanded, reached) pairs",
        description='Fit the correction from PAIRS.json ({"pairs": [{"commanded": [x, y, z], "reached": '
        "[x, y, z]}, ...]}, at least 14 pairs over two heights) and write it for the planner to apply.",
    )
    cal.add_argument("pairs", type=Path, metavar="PAIRS.json", help="the measured pairs")
    cal.add_argument("--out", type=Path, metavar="FILE", help="write the correction here as JSON")
    cal.add_argument("--json", action="store_true", help="print one JSON document instead of a summary")
    cal.set_defaults(handler=run_calibrate)


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--urdf", type=Path, metavar="FILE", help="another arm's URDF (default: the thesis arm)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON document")


def _arm(args: argparse.Namespace) -> ArmModel:
    from planning.arm import ArmModel, ArmModelError

    try:
        return ArmModel.load(args.urdf)
    except ArmModelError as e:
        raise UsageError(f"--urdf: {e}") from e


def _finite(name: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError as e:
        raise UsageError(f"{name}: {text!r} is not a number") from e
    if not math.isfinite(value):
        raise UsageError(f"{name}: must be a finite number, got {text!r}")
    return value


def run_fk(args: argparse.Namespace) -> int:
    arm = _arm(args)
    q = [_finite(f"Q{i}", getattr(args, f"q{i}")) for i in range(1, 6)]
    violations = arm.limit_violations(q)
    if violations:
        raise UsageError(violations[0])
    position, rotation = arm.fk(q)
    if args.json:
        doc = {
            "position_m": [float(v) for v in position],
            "rotation": [[float(v) for v in row] for row in rotation],
        }
        json.dump(doc, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print("grasp point (m): " + " ".join(f"{v:+.4f}" for v in position))
    print("rotation (columns x, y, z; z = approach):")
    for row in rotation:
        print("  " + " ".join(f"{v:+.4f}" for v in row))
    return 0


def run_ik(args: argparse.Namespace) -> int:
    from planning.arm import GraspKind, GraspTarget

    arm = _arm(args)
    target = GraspTarget(
        (_finite("X", args.x), _finite("Y", args.y), _finite("Z", args.z)),
        GraspKind(args.grasp) if args.grasp else GraspKind.POSITION,
    )
    result = arm.ik(target)
    if args.json:
        doc: dict[str, object]
        if result.ok and result.q is not None:
            doc = {"ok": True, "q_rad": list(result.q), "residual_m": result.residual_m}
        else:
            doc = {"ok": False, "error": result.reason}
        json.dump(doc, sys.stdout)
        sys.stdout.write("\n")
    elif result.ok and result.q is not None:
        rows = [
            (n, f"{v:+.4f}", f"{math.degrees(v):+.1f}")
            for n, v in zip(arm.joint_names, result.q, strict=True)
        ]
        print(format_table(("joint", "rad", "deg"), rows))
        print(f"residual: {result.residual_m * 1000:.3f} mm")
    else:
        print(f"dishbot arm ik: no solution: {result.reason}", file=sys.stderr)
    return 0 if result.ok else 1


def run_workspace(args: argparse.Namespace) -> int:
    from planning.motion import check_reachable
    from planning.motion.workspace import describe, served_tray, workspace, workspace_picture

    if args.png is not None and not args.png.parent.resolve().is_dir():
        raise UsageError(f"--png: directory {str(args.png.parent)!r} does not exist")
    arm = _arm(args)
    try:
        config = load_config(args.config)
    except ConfigError as e:
        raise UsageError(f"--config: {e}") from e
    cell = config.cell
    catalogue = config.mug_catalogue()
    ws = workspace(arm, catalogue, tray_floor_m=cell.tray.base_m)
    tray = served_tray(arm, ws, catalogue, tolerance_mm=cell.tolerance_mm)
    problems = check_reachable(cell, arm, catalogue)
    if args.png is not None:
        from cli.pictures import png_with_text, write_atomically

        picture = workspace_picture(arm, cell, ws)
        text = {"Title": picture.title, "Description": "\n".join(picture.texts), "Software": "dishbot arm"}
        write_atomically(args.png, png_with_text(picture.png, text))
    rows = describe(ws)
    if args.json:
        doc = {
            "carry_height_m": ws.carry_z_m,
            "profiles": [dict(zip(("grasp", "mug", "heights", "reach"), r, strict=True)) for r in rows],
            "served_tray": None
            if tray is None
            else {"x_near_m": tray.x_near_m, "x_far_m": tray.x_far_m, "size_mm": list(tray.size_mm)},
            "cell_unreachable": problems,
        }
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_table(("grasp", "mug", "heights", "mug axis distance"), rows))
        if tray is None:
            print("served tray: none")
        else:
            w, d = tray.size_mm
            print(f"largest served tray: {w} x {d} mm, from x = {tray.x_near_m:.2f} m, centred on y = 0")
        print("configured cell: reachable" if not problems else "configured cell: unreachable points:")
        for p in problems:
            print(f"  {p}")
        if args.png is not None:
            print(f"drawn to {args.png}")
    return 0 if not problems else 1


def run_calibrate(args: argparse.Namespace) -> int:
    import numpy as np

    from planning.arm import CalibrationError
    from planning.arm.calibration import fit_correction, load_pairs

    if args.out is not None and not args.out.parent.resolve().is_dir():
        raise UsageError(f"--out: directory {str(args.out.parent)!r} does not exist")
    try:
        commanded, reached = load_pairs(args.pairs)
        correction = fit_correction(commanded, reached)
    except CalibrationError as e:
        raise UsageError(str(e)) from e
    if args.out is not None:
        args.out.write_text(json.dumps(correction.to_mapping(), indent=2) + "\n", encoding="utf-8")
    if args.json:
        json.dump(correction.to_mapping(), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    errors = np.array([correction.rms_before_m, correction.rms_after_m, correction.max_after_m]) * 1000
    print(f"pairs: {correction.pairs}")
    print(
        f"rms error before: {errors[0]:.2f} mm, after: {errors[1]:.2f} mm (worst after: {errors[2]:.2f} mm)"
    )
    if args.out is not None:
        print(f"written to {args.out}")
    return 0
