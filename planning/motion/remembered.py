"""The cycles a planner has planned, remembered by exactly what it was asked (issue 22: a cheap plan check).

The plan check (``planning.placement.checked``) asks the planner the same cycles again and again: each
packing round re-plans from the same start the cycles the round before planned, and the job then plans the
cycles the check chose. A cycle's outcome is a function of what it is asked, so a second asking is answered
from here:

- a plan, by the start, the mug, the slot, the mugs on the tray (in order) and the *set* of other counter
  mugs: whether a move collides does not depend on the order the obstacles are listed in, so neither does
  which alternatives succeed, nor the plan they make;
- a refusal, by the same with the other counter mugs *in order*: a refusal names the first obstacle it met,
  which can depend on that order. It is kept as its text and blockers and raised afresh each time.

Keys hold every argument's fields, each float by its exact value (-0.0 apart from 0.0), so only a
question asked exactly again is answered. The oldest entries go first past ``limit``.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from typing import Generic, TypeVar

from drivers.interfaces import FloatArray
from planning.interfaces import CyclePlan, MotionRefused, MugPose, TraySlot

# A remembered refusal: its text and the mugs that blocked it.
_Refusal = tuple[str, frozenset[str]]
_K = TypeVar("_K", bound=Hashable)
_V = TypeVar("_V")


class RememberedCycles:
    """Plans and refusals of ``plan_cycle``, each under the key that decides it (see the module)."""

    def __init__(self, limit: int = 256) -> None:
        if limit < 1:
            raise ValueError(f"limit must be at least 1, got {limit}")
        self.limit = limit
        self._plans: OrderedDict[Hashable, CyclePlan] = OrderedDict()
        self._refusals: OrderedDict[Hashable, _Refusal] = OrderedDict()
        self.hits = 0
        self.misses = 0

    @staticmethod
    def keys(
        start: Sequence[float] | FloatArray,
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        counter: Sequence[MugPose],
    ) -> tuple[Hashable, Hashable]:
        """(plan key, refusal key) of a cycle: ``counter`` as a set in the first, in order in the second;
        ``mug`` itself is not an obstacle, wherever it is listed."""
        head = (
            tuple(_exact(v) for v in start),
            _mug_key(mug),
            _slot_key(slot),
            tuple(map(_slot_key, on_tray)),
        )
        others = tuple(_mug_key(m) for m in counter if m.mug_id != mug.mug_id)
        return (head, frozenset(others)), (head, others)

    def plan(self, keys: tuple[Hashable, Hashable]) -> CyclePlan | None:
        """The plan remembered under ``keys`` (None: none); raises the refusal remembered under them."""
        plan = self._plans.get(keys[0])
        if plan is not None:
            self._plans.move_to_end(keys[0])
            self.hits += 1
            return plan
        refused = self._refusals.get(keys[1])
        if refused is not None:
            self._refusals.move_to_end(keys[1])
            self.hits += 1
            raise MotionRefused(refused[0], blockers=refused[1])
        self.misses += 1
        return None

    def keep_plan(self, keys: tuple[Hashable, Hashable], plan: CyclePlan) -> None:
        self._plans[keys[0]] = plan
        _trim(self._plans, self.limit)

    def keep_refusal(self, keys: tuple[Hashable, Hashable], refused: MotionRefused) -> None:
        self._refusals[keys[1]] = (str(refused), refused.blockers)
        _trim(self._refusals, self.limit)

    def clear(self) -> None:
        self._plans.clear()
        self._refusals.clear()

    def __len__(self) -> int:
        return len(self._plans) + len(self._refusals)


def _exact(v: float) -> str:
    """A float by its exact value (-0.0 apart from 0.0, as they may not give the same motions)."""
    return float(v).hex()


def _mug_key(m: MugPose) -> tuple[object, ...]:
    return (
        m.mug_id,
        m.type,
        _exact(m.x_m),
        _exact(m.y_m),
        _exact(m.handle_yaw_rad),
        m.upside_down,
        m.handle_seen,
    )


def _slot_key(s: TraySlot) -> tuple[object, ...]:
    yaw = None if s.handle_yaw_rad is None else _exact(s.handle_yaw_rad)
    return (s.mug_id, s.type, _exact(s.x_m), _exact(s.y_m), s.rotated, yaw)


def _trim(entries: OrderedDict[_K, _V], limit: int) -> None:
    while len(entries) > limit:
        entries.popitem(last=False)


class Lru(Generic[_K, _V]):
    """Values computed by a pure function, by their exact arguments (``key``); the least recently used go
    first past ``limit``. The values are shared: callers must not change them."""

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError(f"limit must be at least 1, got {limit}")
        self.limit = limit
        self._entries: OrderedDict[_K, _V] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, key: _K, compute: Callable[[], _V]) -> _V:
        """The value remembered under ``key``, else ``compute()`` (remembered; an exception is not)."""
        try:
            value = self._entries[key]
        except KeyError:
            self.misses += 1
            value = compute()
            self._entries[key] = value
            _trim(self._entries, self.limit)
            return value
        self._entries.move_to_end(key)
        self.hits += 1
        return value

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)
