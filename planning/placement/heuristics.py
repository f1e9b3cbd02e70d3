"""The packing heuristics of §4.2.2 as fill orders, and the frame change that reduces all eight to one.

Tray coordinates put x = 0 at the edge nearest the arm base ("bottom", "top" is far x) and y = 0 at the
robot's right ("left" is large y, the robot's left as seen from above with x up). A heuristic puts each mug at
the free position that comes first in its scan order: BLF scans rows from the bottom, each row from the left;
LBF scans columns from the left, each column from the bottom; T* starts at the top, *R* at the right.

Every heuristic becomes "lowest ``a``, then lowest ``b``" in a canonical frame (``a`` = primary scan axis,
``b`` = secondary), measured from the edge the scan starts at. ``to_canonical``/``from_canonical`` convert a
footprint's corner between the two frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Heuristic(StrEnum):
    BLF = "blf"
    LBF = "lbf"
    TLF = "tlf"
    LTF = "ltf"
    BRF = "brf"
    RBF = "rbf"
    TRF = "trf"
    RTF = "rtf"


@dataclass(frozen=True, slots=True)
class Frame:
    """How a heuristic's canonical (a, b) axes sit in the tray: which tray axis is primary, and whether each
    axis is measured from the far edge (top for x, left for y)."""

    primary_is_x: bool
    x_from_top: bool
    y_from_left: bool

    def sizes(self, tray_mm: tuple[int, int]) -> tuple[int, int]:
        """Tray extent along (a, b)."""
        return tray_mm if self.primary_is_x else (tray_mm[1], tray_mm[0])

    def dims(self, fx: int, fy: int) -> tuple[int, int]:
        """A footprint's extent along (a, b)."""
        return (fx, fy) if self.primary_is_x else (fy, fx)

    def to_canonical(self, tray_mm: tuple[int, int], x: int, y: int, fx: int, fy: int) -> tuple[int, int]:
        u = tray_mm[0] - x - fx if self.x_from_top else x
        v = tray_mm[1] - y - fy if self.y_from_left else y
        return (u, v) if self.primary_is_x else (v, u)

    def from_canonical(self, tray_mm: tuple[int, int], a: int, b: int, fx: int, fy: int) -> tuple[int, int]:
        u, v = (a, b) if self.primary_is_x else (b, a)
        x = tray_mm[0] - u - fx if self.x_from_top else u
        y = tray_mm[1] - v - fy if self.y_from_left else v
        return x, y


FRAMES: dict[Heuristic, Frame] = {
    Heuristic.BLF: Frame(primary_is_x=True, x_from_top=False, y_from_left=True),
    Heuristic.LBF: Frame(primary_is_x=False, x_from_top=False, y_from_left=True),
    Heuristic.TLF: Frame(primary_is_x=True, x_from_top=True, y_from_left=True),
    Heuristic.LTF: Frame(primary_is_x=False, x_from_top=True, y_from_left=True),
    Heuristic.BRF: Frame(primary_is_x=True, x_from_top=False, y_from_left=False),
    Heuristic.RBF: Frame(primary_is_x=False, x_from_top=False, y_from_left=False),
    Heuristic.TRF: Frame(primary_is_x=True, x_from_top=True, y_from_left=False),
    Heuristic.RTF: Frame(primary_is_x=False, x_from_top=True, y_from_left=False),
}


def parse_heuristic(name: str) -> Heuristic:
    try:
        return Heuristic(name.lower())
    except ValueError as e:
        known = ", ".join(h.value for h in Heuristic)
        raise ValueError(f"unknown heuristic {name!r} (known: {known})") from e
