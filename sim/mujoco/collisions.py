"""Collision accounting on the tray: the thesis's "no collisions" requirement, measured.

The thesis tuned the tolerance between footprints until placing made no collisions (§5.3.1, Table 5.19: none
at 1 cm); its collisions were the gripper striking mugs already on the tray when it descended (§5.3.3,
Fig 5.12). ``TrayCollisionCounter`` watches the simulated world's contacts and counts, over the tray:

- ``mug_mug``: two mugs touching (the mug being placed knocks a neighbour, or a placed mug is pushed into
  another);
- ``gripper_mug``: the gripper touching any mug but the one it is handling (the last mug it held).

A contact pair is counted once when it starts and again only after it has been apart for ``rearm_s``, so a
mug resting against a neighbour is one collision, not one per physics tick. ``on_collision`` is called from
the physics thread: it must not block (the daemon hands it to its event loop with ``call_soon_threadsafe``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final, Literal

import structlog

from sim.mujoco.world import ContactSample, SimWorld

log = structlog.get_logger("sim.mujoco.collisions")

CollisionKind = Literal["mug_mug", "gripper_mug"]
GRIPPER: Final = "gripper"


@dataclass(frozen=True, slots=True)
class TrayCollision:
    """One collision over the tray (simulated time, who touched whom, where, how hard)."""

    t: float
    kind: CollisionKind
    a: str  # a mug id, or "gripper"
    b: str  # a mug id
    position_m: tuple[float, float, float]
    force_n: float

    def to_event(self) -> dict[str, object]:
        """The payload of the daemon's ``events`` entry for this collision."""
        return {
            "event": "tray_collision",
            "t": round(self.t, 4),
            "kind": self.kind,
            "a": self.a,
            "b": self.b,
            "position_m": [round(v, 4) for v in self.position_m],
            "force_n": round(self.force_n, 3),
        }


class TrayCollisionCounter:
    """Counts mug-mug and gripper-mug contacts over the tray region of a ``SimWorld``.

    ``tray_region_m`` is (x_min, y_min, x_max, y_max) of the tray's inside; contacts within ``margin_m`` of it
    count too (a mug on the rim). Contacts lighter than ``min_force_n`` are grazes the solver reports at
    zero distance, not collisions.
    """

    def __init__(
        self,
        world: SimWorld,
        tray_region_m: tuple[float, float, float, float],
        *,
        on_collision: Callable[[TrayCollision], None] | None = None,
        min_force_n: float = 0.05,
        rearm_s: float = 0.25,
        margin_m: float = 0.02,
    ) -> None:
        x0, y0, x1, y1 = tray_region_m
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"tray_region_m must be (x_min, y_min, x_max, y_max), got {tray_region_m}")
        if min_force_n < 0 or rearm_s < 0 or margin_m < 0:
            raise ValueError("min_force_n, rearm_s and margin_m must not be negative")
        self._region = (x0 - margin_m, y0 - margin_m, x1 + margin_m, y1 + margin_m)
        self._world = world
        self._listeners: list[Callable[[TrayCollision], None]] = [on_collision] if on_collision else []
        self._min_force = min_force_n
        self._rearm_s = rearm_s
        self._last_seen: dict[tuple[CollisionKind, str, str], float] = {}
        self._handled: str | None = None
        self.collisions: list[TrayCollision] = []
        world.add_contact_listener(self._on_contacts)

    def subscribe(self, listener: Callable[[TrayCollision], None]) -> None:
        """Also call ``listener`` for every new collision (from the physics thread; must not block)."""
        self._listeners.append(listener)

    @property
    def count(self) -> int:
        return len(self.collisions)

    def counts(self) -> dict[CollisionKind, int]:
        out: dict[CollisionKind, int] = {"mug_mug": 0, "gripper_mug": 0}
        for c in self.collisions:
            out[c.kind] += 1
        return out

    def reset(self) -> None:
        with self._world.lock:
            self.collisions.clear()
            self._last_seen.clear()

    def _over_tray(self, p: tuple[float, float, float]) -> bool:
        x0, y0, x1, y1 = self._region
        return x0 <= p[0] <= x1 and y0 <= p[1] <= y1

    def _on_contacts(self, world: SimWorld, t: float, contacts: Sequence[ContactSample]) -> None:
        if world.held_mug is not None:
            self._handled = world.held_mug
        for c in contacts:
            if c.normal_force_n < self._min_force or not self._over_tray(c.position):
                continue
            pair = self._classify(world, c)
            if pair is None:
                continue
            last = self._last_seen.get(pair)
            self._last_seen[pair] = t
            if last is not None and t - last < self._rearm_s:
                continue
            kind, a, b = pair
            collision = TrayCollision(t, kind, a, b, c.position, c.normal_force_n)
            self.collisions.append(collision)
            log.info("tray_collision", kind=kind, a=a, b=b, t=round(t, 3), force_n=round(c.normal_force_n, 2))
            for listener in self._listeners:
                listener(collision)

    def _classify(self, world: SimWorld, c: ContactSample) -> tuple[CollisionKind, str, str] | None:
        m1, m2 = int(world.geom_mug[c.geom1]), int(world.geom_mug[c.geom2])
        if m1 >= 0 and m2 >= 0:
            a, b = sorted((world.mug_ids[m1], world.mug_ids[m2]))
            return ("mug_mug", a, b)
        mug = world.mug_ids[m1 if m1 >= 0 else m2]
        if mug == self._handled:
            return None
        return ("gripper_mug", GRIPPER, mug)
