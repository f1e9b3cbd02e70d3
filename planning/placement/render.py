"""Pictures of a plan: the tray seen from above (x, away from the arm, points up; y, the robot's left, points
left), each mug as it will stand there: its brim, its handle where the arm will turn it, the placing order and
its id, the mug types in colour and the mugs that were already on the tray in grey; rectangle plans also show
each footprint with its tolerance. The tray's size in mm is written along its edges. SVG as text, PNG drawn
with OpenCV (imported only when a PNG is drawn)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from planning.placement.planner import PlanResult
from planning.placement.problem import Problem
from planning.placement.shapes import MugOutline

_MARGIN_MM = 48
_CAPTION_PX = 30
_PALETTE = ("#d9534f", "#337ab7", "#5cb85c", "#f0ad4e", "#9b59b6", "#16a085")
_FIXED = "#9e9e9e"


@dataclass(frozen=True, slots=True)
class _Mug:
    """One mug to draw, in tray millimetres: label inside the brim, id under it."""

    label: str
    mug_id: str
    type: str
    brim: tuple[float, float]
    radius: float
    handle: tuple[tuple[float, float], tuple[float, float]]
    handle_half_thickness: float
    footprint: tuple[float, float, float, float] | None
    colour: str


def _type_colours(problem: Problem) -> dict[str, str]:
    return {name: _PALETTE[i % len(_PALETTE)] for i, name in enumerate(sorted(problem.mug_types))}


def _mug(
    problem: Problem,
    label: str,
    mug_id: str,
    type_name: str,
    corner: tuple[int, int],
    rotated: bool,
    brim: tuple[float, float] | None,
    yaw: float,
    colour: str,
) -> _Mug:
    outline = MugOutline.of(problem.mug_types[type_name])
    bx, by = brim or problem.brim_centre_on_tray(type_name, *corner)
    c, s = math.cos(yaw), math.sin(yaw)
    handle = (
        (bx + outline.handle_from * c, by + outline.handle_from * s),
        (bx + outline.handle_to * c, by + outline.handle_to * s),
    )
    footprint = None
    if problem.footprint_kind == "rect":
        footprint = (corner[0], corner[1], *problem.footprint(type_name, rotated))
    return _Mug(
        label, mug_id, type_name, (bx, by), outline.radius, handle, outline.half_thickness, footprint, colour
    )


def _items(problem: Problem, result: PlanResult) -> list[_Mug]:
    """Every mug drawn, the fixed ones first."""
    colours = _type_colours(problem)
    items = [
        _mug(problem, "", q.id, q.type, (q.x_mm, q.y_mm), q.rotated, None, q.handle_yaw(), _FIXED)
        for q in problem.placed
    ]
    for q in problem.strays:  # where it lies, no footprint of its own (``Problem.obstacle_rects`` has one)
        yaw = 0.0 if q.handle_yaw_rad is None else q.handle_yaw_rad
        stray = _mug(problem, "", q.id, q.type, (0, 0), False, q.brim_mm, yaw, _FIXED)
        items.append(replace(stray, footprint=None))
    for p in result.placed:
        yaw = p.handle_yaw_rad if p.handle_yaw_rad is not None else (math.pi / 2 if p.rotated else 0.0)
        items.append(
            _mug(
                problem,
                str(p.order),
                p.id,
                p.type,
                (p.x_mm, p.y_mm),
                p.rotated,
                p.brim_mm,
                yaw,
                colours[p.type],
            )
        )
    return items


def to_svg(problem: Problem, result: PlanResult, *, scale: float = 1.0) -> str:
    tx, ty = problem.tray_size_mm
    width, height = (ty + 2 * _MARGIN_MM) * scale, (tx + 2 * _MARGIN_MM) * scale + _CAPTION_PX

    def pt(x: float, y: float) -> tuple[float, float]:
        return (_MARGIN_MM + ty - y) * scale, (_MARGIN_MM + tx - x) * scale

    def rect(x: float, y: float, fx: float, fy: float, style: str) -> str:
        left, top = pt(x + fx, y + fy)
        return (
            f'<rect x="{left:.1f}" y="{top:.1f}" width="{fy * scale:.1f}" height="{fx * scale:.1f}" {style}/>'
        )

    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" height="{height:.0f}" '
        f'viewBox="0 0 {width:.0f} {height:.0f}" font-family="sans-serif">',
        f'<rect width="{width:.0f}" height="{height:.0f}" fill="white"/>',
        rect(0, 0, tx, ty, 'fill="#f4f1ea" stroke="black" stroke-width="2"'),
    ]
    (lx, ly), (sx, sy) = pt(tx, ty / 2), pt(tx / 2, 0)
    parts.append(
        f'<text x="{lx:.1f}" y="{ly - 8 * scale:.1f}" font-size="{13 * scale:.0f}" text-anchor="middle">'
        f"{ty} mm (y)</text>"
    )
    parts.append(
        f'<text x="{sx + 6 * scale:.1f}" y="{sy:.1f}" font-size="{13 * scale:.0f}" '
        f'transform="rotate(90 {sx + 6 * scale:.1f} {sy:.1f})" text-anchor="middle">{tx} mm (x)</text>'
    )
    for m in _items(problem, result):
        if m.footprint is not None:
            parts.append(rect(*m.footprint, f'fill="none" stroke="{m.colour}" stroke-dasharray="4 3"'))
        (ax, ay), (bx, by) = (pt(*m.handle[0]), pt(*m.handle[1]))
        parts.append(
            f'<line x1="{ax:.1f}" y1="{ay:.1f}" x2="{bx:.1f}" y2="{by:.1f}" stroke="{m.colour}" '
            f'stroke-width="{2 * m.handle_half_thickness * scale:.1f}" stroke-linecap="round"/>'
        )
        px, py = pt(*m.brim)
        parts.append(
            f'<circle cx="{px:.1f}" cy="{py:.1f}" r="{m.radius * scale:.1f}" fill="{m.colour}" '
            f'fill-opacity="0.35" stroke="{m.colour}" stroke-width="2"><title>{m.type} {m.mug_id}</title>'
            "</circle>"
        )
        if m.label:
            parts.append(
                f'<text x="{px:.1f}" y="{py:.1f}" font-size="{16 * scale:.0f}" font-weight="bold" '
                f'text-anchor="middle">{m.label}</text>'
            )
        parts.append(
            f'<text x="{px:.1f}" y="{py + 15 * scale:.1f}" font-size="{11 * scale:.0f}" '
            f'text-anchor="middle">{m.mug_id}</text>'
        )
    caption = _caption(problem, result)
    parts.append(
        f'<text x="{_MARGIN_MM * scale:.0f}" y="{height - 10:.0f}" font-size="{13 * scale:.0f}">'
        f"{caption}</text>"
    )
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def to_png(problem: Problem, result: PlanResult, *, px_per_mm: float = 1.5) -> bytes:
    import cv2  # only the PNG needs OpenCV

    tx, ty = problem.tray_size_mm
    k = px_per_mm
    img = np.full(
        (int((tx + 2 * _MARGIN_MM) * k) + _CAPTION_PX, int((ty + 2 * _MARGIN_MM) * k), 3), 255, np.uint8
    )
    font = cv2.FONT_HERSHEY_SIMPLEX

    def pt(x: float, y: float) -> tuple[int, int]:
        return round((_MARGIN_MM + ty - y) * k), round((_MARGIN_MM + tx - x) * k)

    def box(r: tuple[float, float, float, float], colour: tuple[int, int, int], thickness: int) -> None:
        x, y, fx, fy = r
        cv2.rectangle(img, pt(x + fx, y + fy), pt(x, y), colour, thickness, cv2.LINE_AA)

    def text(label: str, centre: tuple[int, int], size: float, thickness: int) -> None:
        (w, h), _ = cv2.getTextSize(label, font, size, thickness)
        cv2.putText(
            img,
            label,
            (centre[0] - w // 2, centre[1] + h // 2),
            font,
            size,
            (0, 0, 0),
            thickness,
            cv2.LINE_AA,
        )

    box((0, 0, tx, ty), (234, 241, 244), -1)
    box((0, 0, tx, ty), (0, 0, 0), 2)
    lx, ly = pt(tx, ty / 2)
    text(f"{ty} mm (y)", (lx, ly - round(12 * k)), 0.35 * k, 1)
    sx, sy = pt(tx / 2, 0)
    cv2.putText(img, f"{tx} mm", (sx + 4, sy), font, 0.35 * k, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "(x)", (sx + 4, sy + round(12 * k)), font, 0.35 * k, (0, 0, 0), 1, cv2.LINE_AA)
    for m in _items(problem, result):
        bgr = _bgr(m.colour)
        if m.footprint is not None:
            box(m.footprint, bgr, 1)
        cv2.line(img, pt(*m.handle[0]), pt(*m.handle[1]), bgr, max(1, round(2 * m.handle_half_thickness * k)))
        centre = pt(*m.brim)
        cv2.circle(img, centre, round(m.radius * k), bgr, 2, cv2.LINE_AA)
        if m.label:
            text(m.label, (centre[0], centre[1] - round(6 * k)), 0.5 * k, 2)
        text(m.mug_id, (centre[0], centre[1] + round(10 * k)), 0.3 * k, 1)
    caption = _caption(problem, result)
    cv2.putText(img, caption, (10, img.shape[0] - 10), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    ok, encoded = cv2.imencode(".png", img)
    if not ok:
        raise RuntimeError("png: OpenCV could not encode the picture")
    return bytes(encoded.tobytes())


def _caption(problem: Problem, result: PlanResult) -> str:
    colours = {"#d9534f": "red", "#337ab7": "blue", "#5cb85c": "green", "#f0ad4e": "orange"}
    legend = ", ".join(f"{name} {colours.get(c, c)}" for name, c in _type_colours(problem).items())
    optimal = " (optimal)" if result.optimal else ""
    tx, ty = problem.tray_size_mm
    return (
        f"{result.method}, {problem.footprint_kind}: {result.n} of {result.n + len(result.unplaced)} mugs"
        f"{optimal}; tray {tx} x {ty} mm; {legend}; arm below"
    )


def _bgr(hex_colour: str) -> tuple[int, int, int]:
    r, g, b = (int(hex_colour[i : i + 2], 16) for i in (1, 3, 5))
    return b, g, r
