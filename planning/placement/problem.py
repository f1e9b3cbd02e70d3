"""The placement problem: a tray, a mug catalogue, the mugs on the counter and those already on the tray.

Sizes on the tray are integer millimetres, as the thesis's 1 mm occupancy grid (§4.2.2). Counter positions are
world-frame millimetres (floats). A mug's footprint is its width with handle plus tolerance along tray x and
its brim diameter plus tolerance along tray y; a rotated mug (handle along +y) swaps the two. With
``footprint_kind == "mug"`` a mug is its brim disc plus its handle where the arm turns it (``shapes``); its
spot is still given by that rectangle's corner, whose brim centre is the same.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Annotated, ClassVar

from description import thesis
from planning.placement.errors import InvalidProblem
from validation import (
    FINITE,
    NON_EMPTY,
    UNKNOWN_KEYS_IGNORED,
    Invalid,
    OneOf,
    above,
    convert,
    key_name,
    show,
    within,
)

# "rect": the thesis's rectangle around brim and handle; "mug": the brim disc plus the handle at the yaw the
# arm gives it (``planning.placement.shapes``).
FOOTPRINTS = ("rect", "mug")
# Not from the thesis (it leaves V_a open): a conservative mean end-effector speed for the low-cost arm.
DEFAULT_ARM_SPEED_M_S = 0.1
# World-frame positions and yaws: any finite number (of millimetres, of radians).
WorldMm = Annotated[float, FINITE]
Yaw = Annotated[float, FINITE]


@dataclass(frozen=True, slots=True)
class MugType:
    """One entry of the mug catalogue: brim diameter l, width with handle w, height, mass."""

    name: str
    diameter_mm: int
    width_mm: int
    height_mm: int
    mass_kg: float


@dataclass(frozen=True, slots=True)
class CounterMug:
    """A mug waiting on the counter; ``x_mm``/``y_mm`` is its brim centre in the world frame, and
    ``handle_yaw_rad`` where its handle points (world yaw), None when unknown. It is also the shape of a
    problem file's ``mugs`` entry (keys it does not declare are passed over)."""

    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    id: Annotated[str, NON_EMPTY]
    type: str
    x_mm: WorldMm
    y_mm: WorldMm
    handle_yaw_rad: Yaw | None = None


@dataclass(frozen=True, slots=True)
class TrayMug:
    """A mug already on the tray (replanning): footprint corner in tray coordinates, and where its handle
    points (tray frame, 0 = +x) when known; None: along +x, or +y when rotated."""

    id: str
    type: str
    x_mm: int
    y_mm: int
    rotated: bool = False
    handle_yaw_rad: float | None = None

    def handle_yaw(self) -> float:
        if self.handle_yaw_rad is not None:
            return self.handle_yaw_rad
        return math.pi / 2 if self.rotated else 0.0


@dataclass(frozen=True, slots=True)
class TrayStray:
    """A mug lying on the tray where no plan put it (it fell there on the way, or someone set it down): an
    obstacle the layout keeps clear of. Unlike a ``TrayMug`` it may stand anywhere: partly off the tray,
    closer than the tolerance to another mug. ``brim_mm`` is its brim centre in tray coordinates;
    ``handle_yaw_rad`` where its handle points (tray frame), None when unseen: then every direction is
    kept clear."""

    id: str
    type: str
    brim_mm: tuple[float, float]
    handle_yaw_rad: float | None = None


def default_mug_types() -> dict[str, MugType]:
    """The thesis catalogue (§5.3): big and small mugs."""
    return {
        m.name: MugType(m.name, m.diameter_mm, m.width_mm, m.height_mm, m.mass_kg)
        for m in thesis.MUG_TYPES.values()
    }


@dataclass(frozen=True)
class Problem:
    """Everything the placement planner needs; build it with ``from_json`` to get validation."""

    tray_size_mm: tuple[int, int]
    tray_origin_mm: tuple[float, float]
    mugs: tuple[CounterMug, ...]
    mug_types: Mapping[str, MugType] = field(default_factory=default_mug_types)
    placed: tuple[TrayMug, ...] = ()
    tolerance_mm: int = thesis.TOLERANCE_MM
    allow_rotation: bool = False
    arm_base_mm: tuple[float, float] = (0.0, 0.0)
    arm_speed_m_s: float = DEFAULT_ARM_SPEED_M_S
    footprint_kind: str = "rect"  # one of FOOTPRINTS; "footprint" in the problem format
    strays: tuple[TrayStray, ...] = ()  # mugs lying on the tray where no plan put them: obstacles

    def __post_init__(self) -> None:
        _check_consistency(self)

    def obstacle_rects(self) -> list[tuple[int, int, int, int]]:
        """The tray's occupied rectangles (x, y, extent x, extent y; mm, tray coordinates) for the rectangle
        packers: each placed mug's footprint, and for a stray the square its brim and handle can sweep (the
        handle at any yaw) grown by half the tolerance, cut to the tray (a stray wholly off it is none)."""
        rects = [(q.x_mm, q.y_mm, *self.footprint(q.type, q.rotated)) for q in self.placed]
        tx, ty = self.tray_size_mm
        for s in self.strays:
            t = self.mug_types[s.type]
            half = t.width_mm - t.diameter_mm / 2.0 + self.tolerance_mm / 2.0
            x0 = max(0, math.floor(s.brim_mm[0] - half))
            y0 = max(0, math.floor(s.brim_mm[1] - half))
            x1 = min(tx, math.ceil(s.brim_mm[0] + half))
            y1 = min(ty, math.ceil(s.brim_mm[1] + half))
            if x0 < x1 and y0 < y1:
                rects.append((x0, y0, x1 - x0, y1 - y0))
        return rects

    def footprint(self, type_name: str, rotated: bool = False) -> tuple[int, int]:
        """Footprint extent (along tray x, along tray y) in mm, tolerance included."""
        t = self.mug_types[type_name]
        fx, fy = t.width_mm + self.tolerance_mm, t.diameter_mm + self.tolerance_mm
        return (fy, fx) if rotated else (fx, fy)

    def brim_centre_on_tray(self, type_name: str, x_mm: float, y_mm: float) -> tuple[float, float]:
        """The brim centre (tray coordinates) of a mug whose footprint corner is at (x_mm, y_mm).

        The handle points along +x (or +y when rotated), so the brim sits at the footprint's low corner in
        both orientations, half a tolerance in from the edge."""
        t = self.mug_types[type_name]
        r = (t.diameter_mm + self.tolerance_mm) / 2.0
        return x_mm + r, y_mm + r

    def to_world_mm(self, tray_x_mm: float, tray_y_mm: float) -> tuple[float, float]:
        return self.tray_origin_mm[0] + tray_x_mm, self.tray_origin_mm[1] + tray_y_mm

    def relative_yaw(self, mug_index: int) -> float:
        """What a counter mug's handle adds to the slot's bearing once placed: pick bearing - counter yaw
        (no wrist yaw: the side grasp keeps the handle's angle to the gripper and the flip mirrors it; the
        model of ``CyclePlan.handle_yaw_rad``). 0 for a mug whose handle yaw is unknown: the simulated
        counters set every mug out with its handle pointing away from the arm."""
        m = self.mugs[mug_index]
        if m.handle_yaw_rad is None:
            return 0.0
        bx, by = self.arm_base_mm
        return math.remainder(math.atan2(m.y_mm - by, m.x_mm - bx) - m.handle_yaw_rad, math.tau)

    def handle_yaw_on_tray(self, brim_x_mm: float, brim_y_mm: float, relative_rad: float) -> float:
        """The handle's yaw (tray frame, 0 = +x; the tray's axes are the world's) of a mug placed with its
        brim centre at (x, y) in tray coordinates: the slot's bearing from the arm base plus
        ``relative_rad`` (``relative_yaw``)."""
        wx, wy = self.to_world_mm(brim_x_mm, brim_y_mm)
        bx, by = self.arm_base_mm
        return math.remainder(math.atan2(wy - by, wx - bx) + relative_rad, math.tau)

    @classmethod
    def from_json(cls, obj: object) -> Problem:
        """The ``dishbot plan`` problem format (a decoded JSON value), checked by the one validator against
        its declared shape (below) and then as a whole; ``InvalidProblem``, one line naming the field,
        otherwise."""
        return _parse(obj)

    def to_json(self) -> dict[str, object]:
        return {
            "tray": {"size_mm": list(self.tray_size_mm), "origin_mm": list(self.tray_origin_mm)},
            "tolerance_mm": self.tolerance_mm,
            "allow_rotation": self.allow_rotation,
            "footprint": self.footprint_kind,
            "arm": {"base_mm": list(self.arm_base_mm), "speed_m_s": self.arm_speed_m_s},
            "mug_types": {
                t.name: {
                    "diameter_mm": t.diameter_mm,
                    "width_mm": t.width_mm,
                    "height_mm": t.height_mm,
                    "mass_kg": t.mass_kg,
                }
                for t in self.mug_types.values()
            },
            "mugs": [
                {"id": m.id, "type": m.type, "x_mm": m.x_mm, "y_mm": m.y_mm}
                | ({} if m.handle_yaw_rad is None else {"handle_yaw_rad": m.handle_yaw_rad})
                for m in self.mugs
            ],
            "placed": [
                {"id": p.id, "type": p.type, "x_mm": p.x_mm, "y_mm": p.y_mm, "rotated": p.rotated}
                | ({} if p.handle_yaw_rad is None else {"handle_yaw_rad": p.handle_yaw_rad})
                for p in self.placed
            ],
        } | (  # only when there are strays: a problem without any writes what it always wrote
            {}
            if not self.strays
            else {
                "strays": [
                    {"id": s.id, "type": s.type, "brim_mm": list(s.brim_mm)}
                    | ({} if s.handle_yaw_rad is None else {"handle_yaw_rad": s.handle_yaw_rad})
                    for s in self.strays
                ]
            }
        )


# --- the problem file's shape (``validation.convert`` checks a decoded file against it) ---------------------
# Sizes on the tray are whole millimetres; a file may write them as 475 or 475.0 (JSON has one number type),
# so they are declared as numbers and held whole by the tables' own rule. Keys a table inside the problem
# does not declare are passed over, as they always were (a result's ``placed`` entry, with its ``order``
# and ``brim_mm``, is a problem's ``placed`` entry); an unknown key at the top is refused.

TraySize = Annotated[float, above(0, 10_000, unit="mm")]
TrayCoordinate = Annotated[float, within(0, 10_000, unit="mm")]
MugSize = Annotated[float, above(0, 1_000, unit="mm")]
Tolerance = Annotated[float, within(0, 1_000, unit="mm")]
MugMass = Annotated[float, above(0, 100, unit="kg")]
ArmSpeed = Annotated[float, above(0, 100, unit="m/s")]


def _whole(name: str, value: float) -> int:
    if not float(value).is_integer():
        raise Invalid(f"{name}: expected whole millimetres, got {show(value)}")
    return int(value)


@dataclass(frozen=True, slots=True)
class _TrayTable:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    size_mm: tuple[TraySize, TraySize]
    origin_mm: tuple[WorldMm, WorldMm] | None = None

    def __post_init__(self) -> None:
        for i, v in enumerate(self.size_mm):
            _whole(f"size_mm[{i}]", v)


@dataclass(frozen=True, slots=True)
class _MugTypeTable:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    diameter_mm: MugSize
    width_mm: MugSize
    height_mm: MugSize
    mass_kg: MugMass

    def __post_init__(self) -> None:
        for key in ("diameter_mm", "width_mm", "height_mm"):
            _whole(key, getattr(self, key))
        if self.width_mm < self.diameter_mm:
            raise Invalid(
                f"width_mm: {show(self.width_mm)} is less than the brim diameter {show(self.diameter_mm)}"
                " (width includes the handle)"
            )


@dataclass(frozen=True, slots=True)
class _TrayMugTable:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    id: Annotated[str, NON_EMPTY]
    type: str
    x_mm: TrayCoordinate
    y_mm: TrayCoordinate
    rotated: bool = False
    handle_yaw_rad: Yaw | None = None

    def __post_init__(self) -> None:
        _whole("x_mm", self.x_mm)
        _whole("y_mm", self.y_mm)


@dataclass(frozen=True, slots=True)
class _StrayTable:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    id: Annotated[str, NON_EMPTY]
    type: str
    brim_mm: tuple[WorldMm, WorldMm]
    handle_yaw_rad: Yaw | None = None


@dataclass(frozen=True, slots=True)
class _ArmTable:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    base_mm: tuple[WorldMm, WorldMm] | None = None
    speed_m_s: ArmSpeed = DEFAULT_ARM_SPEED_M_S


@dataclass(frozen=True, slots=True)
class _ProblemFile:
    tray: _TrayTable
    mugs: tuple[CounterMug, ...]
    tolerance_mm: Tolerance = thesis.TOLERANCE_MM
    allow_rotation: bool = False
    footprint: Annotated[str, OneOf(FOOTPRINTS)] = "rect"
    # absent (or null): the thesis's two mugs; each entry is a ``_MugTypeTable``, checked by ``_mug_types``
    # so that a message names its mug type (msgspec does not say which key of a table it was at)
    mug_types: dict[str, object] | None = None
    placed: tuple[_TrayMugTable, ...] = ()
    strays: tuple[_StrayTable, ...] = ()
    arm: _ArmTable | None = None

    def __post_init__(self) -> None:
        _whole("tolerance_mm", self.tolerance_mm)
        if self.mug_types is not None and not self.mug_types:
            raise Invalid("mug_types: must name at least one mug type")


def _mug_types(tables: Mapping[str, object]) -> dict[str, MugType]:
    types = {}
    for name, table in tables.items():
        t = convert(table, _MugTypeTable, name=key_name("mug_types", name), error=InvalidProblem)
        types[name] = MugType(name, int(t.diameter_mm), int(t.width_mm), int(t.height_mm), t.mass_kg)
    return types


def _parse(obj: object) -> Problem:
    f = convert(obj, _ProblemFile, error=InvalidProblem, root="the problem")
    types = default_mug_types() if f.mug_types is None else _mug_types(f.mug_types)
    arm = f.arm or _ArmTable()
    return Problem(
        tray_size_mm=(int(f.tray.size_mm[0]), int(f.tray.size_mm[1])),
        tray_origin_mm=f.tray.origin_mm or (0.0, 0.0),
        mugs=f.mugs,
        mug_types=types,
        placed=tuple(
            TrayMug(q.id, q.type, int(q.x_mm), int(q.y_mm), q.rotated, q.handle_yaw_rad) for q in f.placed
        ),
        tolerance_mm=int(f.tolerance_mm),
        allow_rotation=f.allow_rotation,
        arm_base_mm=arm.base_mm or (0.0, 0.0),
        arm_speed_m_s=arm.speed_m_s,
        footprint_kind=f.footprint,
        strays=tuple(TrayStray(q.id, q.type, q.brim_mm, q.handle_yaw_rad) for q in f.strays),
    )


def _check_consistency(p: Problem) -> None:
    """Checks that hold however the problem was built: sizes, ids, on-tray mugs inside and apart."""
    tx, ty = p.tray_size_mm
    if tx <= 0 or ty <= 0:
        raise InvalidProblem(f"tray.size_mm: both extents must be positive, got [{tx}, {ty}]")
    if p.tolerance_mm < 0:
        raise InvalidProblem(f"tolerance_mm: must be 0 or more, got {p.tolerance_mm}")
    if p.footprint_kind not in FOOTPRINTS:
        raise InvalidProblem(f"footprint: expected one of {', '.join(FOOTPRINTS)}, got {p.footprint_kind!r}")
    if p.footprint_kind == "mug" and p.allow_rotation:
        raise InvalidProblem(
            "allow_rotation: mug-shaped footprints turn each handle as the arm does;"
            " rotation needs footprint rect"
        )
    ids: set[str] = set()
    entries = [("mugs", i, m.id, m.type) for i, m in enumerate(p.mugs)]
    entries += [("placed", i, q.id, q.type) for i, q in enumerate(p.placed)]
    entries += [("strays", i, q.id, q.type) for i, q in enumerate(p.strays)]
    for group, i, mug_id, type_name in entries:
        if type_name not in p.mug_types:
            known = ", ".join(sorted(p.mug_types))
            raise InvalidProblem(f"{group}[{i}].type: unknown mug type {type_name!r} (known: {known})")
        if mug_id in ids:
            raise InvalidProblem(f"{group}[{i}].id: duplicate mug id {mug_id!r}")
        ids.add(mug_id)
    for i, m in enumerate(p.mugs):
        if not (math.isfinite(m.x_mm) and math.isfinite(m.y_mm)):
            raise InvalidProblem(f"mugs[{i}]: position must be finite, got ({m.x_mm}, {m.y_mm})")
        fits = [p.footprint(m.type, r) for r in ((False, True) if p.allow_rotation else (False,))]
        if not any(fx <= tx and fy <= ty for fx, fy in fits):
            fx, fy = fits[0]
            raise InvalidProblem(
                f"mugs[{i}].type: a {m.type!r} mug ({fx} x {fy} mm with tolerance) is larger than the tray"
                f" ({tx} x {ty} mm)"
            )
    if p.footprint_kind == "mug":
        _check_placed_outlines(p)
        return
    rects: list[tuple[int, int, int, int]] = []
    for i, q in enumerate(p.placed):
        fx, fy = p.footprint(q.type, q.rotated)
        if q.x_mm < 0 or q.y_mm < 0 or q.x_mm + fx > tx or q.y_mm + fy > ty:
            raise InvalidProblem(
                f"placed[{i}]: footprint [{q.x_mm}, {q.x_mm + fx}] x [{q.y_mm}, {q.y_mm + fy}] mm"
                f" leaves the tray ({tx} x {ty} mm)"
            )
        for j, (x0, y0, x1, y1) in enumerate(rects):
            if q.x_mm < x1 and x0 < q.x_mm + fx and q.y_mm < y1 and y0 < q.y_mm + fy:
                raise InvalidProblem(f"placed[{i}]: overlaps placed[{j}] (footprints with tolerance)")
        rects.append((q.x_mm, q.y_mm, q.x_mm + fx, q.y_mm + fy))


def _check_placed_outlines(p: Problem) -> None:
    """Mugs on the tray as outlines (brim and handle where it points): inside the walls by half the
    tolerance, the tolerance apart."""
    import numpy as np  # only mug-shaped replanning needs it; problems load without numpy

    from planning.placement import shapes

    tx, ty = p.tray_size_mm
    bodies: list[shapes.Bodies] = []
    for i, q in enumerate(p.placed):
        if q.rotated:
            raise InvalidProblem(f"placed[{i}].rotated: mug-shaped footprints are never rotated")
        cx, cy = p.brim_centre_on_tray(q.type, q.x_mm, q.y_mm)
        b = shapes.Bodies.build(
            shapes.MugOutline.of(p.mug_types[q.type]),
            np.array([cx]),
            np.array([cy]),
            np.array([q.handle_yaw()]),
        )
        if not shapes.keeps_clear(b.wall_gap((tx, ty)), p.tolerance_mm / 2.0)[0]:
            raise InvalidProblem(
                f"placed[{i}]: brim centre ({cx:g}, {cy:g}) mm: the mug and its handle leave the tray"
                f" ({tx} x {ty} mm, {p.tolerance_mm / 2:g} mm from the walls)"
            )
        for j, other in enumerate(bodies):
            if not shapes.keeps_clear(b.gap_to(other, 0), float(p.tolerance_mm))[0]:
                raise InvalidProblem(
                    f"placed[{i}]: closer than {p.tolerance_mm} mm to placed[{j}] (mug outlines)"
                )
        bodies.append(b)
