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

from description import thesis
from planning.placement.errors import InvalidProblem

# "rect": the thesis's rectangle around brim and handle; "mug": the brim disc plus the handle at the yaw the
# arm gives it (``planning.placement.shapes``).
FOOTPRINTS = ("rect", "mug")
# Not from the thesis (it leaves V_a open): a conservative mean end-effector speed for the low-cost arm.
DEFAULT_ARM_SPEED_M_S = 0.1


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
    ``handle_yaw_rad`` where its handle points (world yaw), None when unknown."""

    id: str
    type: str
    x_mm: float
    y_mm: float
    handle_yaw_rad: float | None = None


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

    def __post_init__(self) -> None:
        _check_consistency(self)

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
    def from_json(cls, obj: Mapping[str, object]) -> Problem:
        """Parse and validate the ``dishbot plan`` problem format; ``InvalidProblem`` names the bad field."""
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
        }


def _parse(obj: Mapping[str, object]) -> Problem:
    if not isinstance(obj, Mapping):
        raise InvalidProblem(f"problem: expected a JSON object, got {_kind(obj)}")
    known = {"tray", "tolerance_mm", "allow_rotation", "footprint", "mug_types", "mugs", "placed", "arm"}
    for key in obj:
        if key not in known:
            raise InvalidProblem(f"{key}: unknown field (known: {', '.join(sorted(known))})")
    tray = _mapping(obj, "tray", required=True)
    size = _pair(tray, "size_mm", "tray.size_mm", integer=True, positive=True, required=True)
    assert size is not None  # required=True
    origin = _pair(tray, "origin_mm", "tray.origin_mm", integer=False, positive=False, required=False)
    tolerance = _number(
        obj, "tolerance_mm", "tolerance_mm", integer=True, minimum=0, default=thesis.TOLERANCE_MM
    )
    rotation = obj.get("allow_rotation", False)
    if not isinstance(rotation, bool):
        raise InvalidProblem(f"allow_rotation: expected true or false, got {_kind(rotation)}")
    footprint = obj.get("footprint", "rect")
    if footprint not in FOOTPRINTS:
        raise InvalidProblem(f"footprint: expected one of {', '.join(FOOTPRINTS)}, got {_kind(footprint)}")
    types = _parse_types(obj)
    arm = _mapping(obj, "arm", required=False)
    base = _pair(arm, "base_mm", "arm.base_mm", integer=False, positive=False, required=False)
    speed = _number(
        arm, "speed_m_s", "arm.speed_m_s", integer=False, minimum=None, default=DEFAULT_ARM_SPEED_M_S
    )
    if speed <= 0:
        raise InvalidProblem(f"arm.speed_m_s: must be positive, got {speed}")
    mugs_raw = obj.get("mugs")
    if not isinstance(mugs_raw, list):
        raise InvalidProblem(f"mugs: expected a list of mugs, got {_kind(mugs_raw)}")
    mugs = tuple(_parse_counter_mug(m, f"mugs[{i}]", types) for i, m in enumerate(mugs_raw))
    placed_raw = obj.get("placed", [])
    if not isinstance(placed_raw, list):
        raise InvalidProblem(f"placed: expected a list of mugs, got {_kind(placed_raw)}")
    placed = tuple(_parse_tray_mug(m, f"placed[{i}]", types) for i, m in enumerate(placed_raw))
    return Problem(
        tray_size_mm=(int(size[0]), int(size[1])),
        tray_origin_mm=(float(origin[0]), float(origin[1])) if origin else (0.0, 0.0),
        mugs=mugs,
        mug_types=types,
        placed=placed,
        tolerance_mm=int(tolerance),
        allow_rotation=rotation,
        arm_base_mm=(float(base[0]), float(base[1])) if base else (0.0, 0.0),
        arm_speed_m_s=float(speed),
        footprint_kind=str(footprint),
    )


def _parse_types(obj: Mapping[str, object]) -> dict[str, MugType]:
    if "mug_types" not in obj:
        return default_mug_types()
    raw = _mapping(obj, "mug_types", required=True)
    if not raw:
        raise InvalidProblem("mug_types: must name at least one mug type")
    types: dict[str, MugType] = {}
    for name, spec in raw.items():
        where = f"mug_types.{name}"
        if not isinstance(spec, Mapping):
            raise InvalidProblem(f"{where}: expected an object, got {_kind(spec)}")
        dims = {
            key: int(_number(spec, key, f"{where}.{key}", integer=True, minimum=1, default=None))
            for key in ("diameter_mm", "width_mm", "height_mm")
        }
        mass = _number(spec, "mass_kg", f"{where}.mass_kg", integer=False, minimum=None, default=None)
        if mass <= 0:
            raise InvalidProblem(f"{where}.mass_kg: must be positive, got {mass}")
        if dims["width_mm"] < dims["diameter_mm"]:
            raise InvalidProblem(
                f"{where}.width_mm: {dims['width_mm']} is less than the brim diameter {dims['diameter_mm']}"
                " (width includes the handle)"
            )
        types[str(name)] = MugType(str(name), dims["diameter_mm"], dims["width_mm"], dims["height_mm"], mass)
    return types


def _parse_counter_mug(raw: object, where: str, types: Mapping[str, MugType]) -> CounterMug:
    if not isinstance(raw, Mapping):
        raise InvalidProblem(f"{where}: expected an object, got {_kind(raw)}")
    mug_id, type_name = _id_and_type(raw, where, types)
    x = _number(raw, "x_mm", f"{where}.x_mm", integer=False, minimum=None, default=None)
    y = _number(raw, "y_mm", f"{where}.y_mm", integer=False, minimum=None, default=None)
    return CounterMug(mug_id, type_name, float(x), float(y), _yaw(raw, where))


def _parse_tray_mug(raw: object, where: str, types: Mapping[str, MugType]) -> TrayMug:
    if not isinstance(raw, Mapping):
        raise InvalidProblem(f"{where}: expected an object, got {_kind(raw)}")
    mug_id, type_name = _id_and_type(raw, where, types)
    x = _number(raw, "x_mm", f"{where}.x_mm", integer=True, minimum=0, default=None)
    y = _number(raw, "y_mm", f"{where}.y_mm", integer=True, minimum=0, default=None)
    rotated = raw.get("rotated", False)
    if not isinstance(rotated, bool):
        raise InvalidProblem(f"{where}.rotated: expected true or false, got {_kind(rotated)}")
    return TrayMug(mug_id, type_name, int(x), int(y), rotated, _yaw(raw, where))


def _yaw(raw: Mapping[str, object], where: str) -> float | None:
    if "handle_yaw_rad" not in raw:
        return None
    return _check_number(raw["handle_yaw_rad"], f"{where}.handle_yaw_rad", integer=False, minimum=None)


def _id_and_type(raw: Mapping[str, object], where: str, types: Mapping[str, MugType]) -> tuple[str, str]:
    mug_id = raw.get("id")
    if not isinstance(mug_id, str) or not mug_id:
        raise InvalidProblem(f"{where}.id: expected a non-empty string, got {_kind(mug_id)}")
    type_name = raw.get("type")
    if not isinstance(type_name, str):
        raise InvalidProblem(f"{where}.type: expected a mug type name, got {_kind(type_name)}")
    if type_name not in types:
        raise InvalidProblem(
            f"{where}.type: unknown mug type {type_name!r} (known: {', '.join(sorted(types))})"
        )
    return mug_id, type_name


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


def _mapping(obj: Mapping[str, object], key: str, *, required: bool) -> Mapping[str, object]:
    value = obj.get(key)
    if value is None and not required:
        return {}
    if not isinstance(value, Mapping):
        raise InvalidProblem(f"{key}: expected an object, got {_kind(value)}")
    return value


def _pair(
    obj: Mapping[str, object], key: str, where: str, *, integer: bool, positive: bool, required: bool
) -> tuple[float, float] | None:
    value = obj.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, list) or len(value) != 2:
        raise InvalidProblem(f"{where}: expected a list of two numbers [x, y], got {_kind(value)}")
    out = []
    for i, v in enumerate(value):
        out.append(_check_number(v, f"{where}[{i}]", integer=integer, minimum=1 if positive else None))
    return out[0], out[1]


def _number(
    obj: Mapping[str, object],
    key: str,
    where: str,
    *,
    integer: bool,
    minimum: float | None,
    default: float | None,
) -> float:
    if key not in obj:
        if default is None:
            raise InvalidProblem(f"{where}: missing")
        return default
    return _check_number(obj[key], where, integer=integer, minimum=minimum)


def _check_number(value: object, where: str, *, integer: bool, minimum: float | None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidProblem(f"{where}: expected a number, got {_kind(value)}")
    if not math.isfinite(value):
        raise InvalidProblem(f"{where}: expected a finite number, got {value}")
    if integer and value != int(value):
        raise InvalidProblem(f"{where}: expected whole millimetres, got {value}")
    if minimum is not None and value < minimum:
        what = "positive" if minimum == 1 else f"at least {minimum}"
        raise InvalidProblem(f"{where}: must be {what}, got {value}")
    return float(value)


def _kind(value: object) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, int | float):
        return f"a number ({value})"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, Mapping):
        return "an object"
    return type(value).__name__
