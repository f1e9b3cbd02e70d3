"""Pictures of a plan: the tray seen from above (x, away from the arm, points up; y, the robot's left, points
left), each footprint with its tolerance, the brim and handle, the placing order, mug types in colour, and the
mugs that were already on the tray in grey. SVG as text, PNG drawn with OpenCV."""

from __future__ import annotations

import cv2
import numpy as np

from planning.placement.planner import PlanResult
from planning.placement.problem import Problem

_MARGIN_MM = 20
_PALETTE = ("#d9534f", "#337ab7", "#5cb85c", "#f0ad4e", "#9b59b6", "#16a085")
_FIXED = "#9e9e9e"


def _type_colours(problem: Problem) -> dict[str, str]:
    return {name: _PALETTE[i % len(_PALETTE)] for i, name in enumerate(sorted(problem.mug_types))}


def _items(problem: Problem, result: PlanResult) -> list[tuple[str, str, int, int, bool, str]]:
    """(label, type, x, y, rotated, colour) for every mug drawn, fixed ones first."""
    colours = _type_colours(problem)
    items = [(q.id, q.type, q.x_mm, q.y_mm, q.rotated, _FIXED) for q in problem.placed]
    items += [(str(p.order), p.type, p.x_mm, p.y_mm, p.rotated, colours[p.type]) for p in result.placed]
    return items


def _shapes(
    problem: Problem, type_name: str, x: int, y: int, rotated: bool
) -> dict[str, tuple[float, float, float, float]]:
    """Footprint, brim circle and handle rectangle in tray millimetres."""
    t = problem.mug_types[type_name]
    fx, fy = problem.footprint(type_name, rotated)
    cx, cy = problem.brim_centre_on_tray(type_name, x, y)
    r = t.diameter_mm / 2.0
    reach = t.width_mm - t.diameter_mm
    grip = max(t.diameter_mm / 4.0, 4.0)
    handle = (cx - grip / 2, cy + r, grip, reach) if rotated else (cx + r, cy - grip / 2, reach, grip)
    return {"footprint": (x, y, fx, fy), "brim": (cx, cy, r, r), "handle": handle}


def to_svg(problem: Problem, result: PlanResult, *, scale: float = 1.0) -> str:
    tx, ty = problem.tray_size_mm
    width, height = (ty + 2 * _MARGIN_MM) * scale, (tx + 2 * _MARGIN_MM + 30) * scale

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
    for label, type_name, x, y, rotated, colour in _items(problem, result):
        s = _shapes(problem, type_name, x, y, rotated)
        parts.append(rect(*s["footprint"], f'fill="none" stroke="{colour}" stroke-dasharray="4 3"'))
        parts.append(rect(*s["handle"], f'fill="{colour}" fill-opacity="0.6" stroke="{colour}"'))
        cx, cy, r, _ = s["brim"]
        px, py = pt(cx, cy)
        parts.append(
            f'<circle cx="{px:.1f}" cy="{py:.1f}" r="{r * scale:.1f}" fill="{colour}" fill-opacity="0.35" '
            f'stroke="{colour}" stroke-width="2"><title>{type_name} {label}</title></circle>'
        )
        parts.append(
            f'<text x="{px:.1f}" y="{py + 5 * scale:.1f}" font-size="{14 * scale:.0f}" text-anchor="middle">'
            f"{label}</text>"
        )
    caption = _caption(problem, result)
    parts.append(
        f'<text x="{_MARGIN_MM * scale:.0f}" y="{height - 10 * scale:.0f}" font-size="{13 * scale:.0f}">'
        f"{caption}</text>"
    )
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def to_png(problem: Problem, result: PlanResult, *, px_per_mm: float = 1.5) -> bytes:
    tx, ty = problem.tray_size_mm
    k = px_per_mm
    img = np.full((int((tx + 2 * _MARGIN_MM) * k) + 30, int((ty + 2 * _MARGIN_MM) * k), 3), 255, np.uint8)

    def pt(x: float, y: float) -> tuple[int, int]:
        return round((_MARGIN_MM + ty - y) * k), round((_MARGIN_MM + tx - x) * k)

    def box(r: tuple[float, float, float, float], colour: tuple[int, int, int], thickness: int) -> None:
        x, y, fx, fy = r
        cv2.rectangle(img, pt(x + fx, y + fy), pt(x, y), colour, thickness, cv2.LINE_AA)

    box((0, 0, tx, ty), (234, 241, 244), -1)
    box((0, 0, tx, ty), (0, 0, 0), 2)
    for label, type_name, x, y, rotated, colour in _items(problem, result):
        bgr = _bgr(colour)
        s = _shapes(problem, type_name, x, y, rotated)
        box(s["footprint"], bgr, 1)
        box(s["handle"], bgr, -1)
        cx, cy, r, _ = s["brim"]
        cv2.circle(img, pt(cx, cy), round(r * k), bgr, 2, cv2.LINE_AA)
        size, _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.5 * k, 1)
        px, py = pt(cx, cy)
        cv2.putText(
            img,
            label,
            (px - size[0] // 2, py + size[1] // 2),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5 * k,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    caption = _caption(problem, result)
    cv2.putText(
        img, caption, (10, img.shape[0] - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA
    )
    ok, encoded = cv2.imencode(".png", img)
    if not ok:
        raise RuntimeError("png: OpenCV could not encode the picture")
    return bytes(encoded.tobytes())


def _caption(problem: Problem, result: PlanResult) -> str:
    colours = {"#d9534f": "red", "#337ab7": "blue", "#5cb85c": "green", "#f0ad4e": "orange"}
    legend = ", ".join(f"{name} {colours.get(c, c)}" for name, c in _type_colours(problem).items())
    optimal = " (optimal)" if result.optimal else ""
    return (
        f"{result.method}: {result.n} of {result.n + len(result.unplaced)} mugs{optimal}; {legend}; arm below"
    )


def _bgr(hex_colour: str) -> tuple[int, int, int]:
    r, g, b = (int(hex_colour[i : i + 2], 16) for i in (1, 3, 5))
    return b, g, r
