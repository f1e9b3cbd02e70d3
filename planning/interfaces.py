"""The seams between planning and the rest: placement problems go in, cycle plans of joint motions come out.

The placement planner itself lives in ``planning.placement`` (problem and result formats are the JSON
contract of ``dishbot plan``; its seam is ``planning.placement.PlacementPlanner``), the cycle planner in
``planning.motion``; the daemon's job depends only on the protocols below (``MotionPlanner``) and that seam.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:  # only annotations here: the placement planner's users need not load numpy
    from drivers.interfaces import JointTrajectory


@dataclass(frozen=True, slots=True)
class MugPose:
    """A mug on the counter as manipulation needs it (world frame, metres)."""

    mug_id: str
    type: str
    x_m: float
    y_m: float
    handle_yaw_rad: float = 0.0
    upside_down: bool = False
    handle_seen: bool = True  # False: handle_yaw_rad is a guess (the camera did not see the handle)


@dataclass(frozen=True, slots=True)
class TraySlot:
    """Where a mug goes (or is) on the tray: its axis in the world frame, handle along +x unless rotated."""

    mug_id: str
    type: str
    x_m: float
    y_m: float
    rotated: bool = False
    # Where the handle of the mug placed there points (world yaw), when known; None: along +x (+y rotated).
    handle_yaw_rad: float | None = None


class StepKind(StrEnum):
    MOVE = "move"  # follow ``trajectory``
    CLOSE = "close"  # close the gripper on the mug and verify the grasp
    OPEN = "open"  # release the mug


@dataclass(frozen=True, slots=True)
class Step:
    """One action of a pick-flip-place cycle. ``phase`` is the statechart state it belongs to, e.g.
    ``side_grasp.approach`` or ``place.release``. An OPEN step opens the gripper to ``aperture_m`` (metres
    between the pads), or fully when it is None: between close neighbours on the tray a full opening would
    swing the finger into the next mug."""

    phase: str
    kind: StepKind
    trajectory: JointTrajectory | None = None
    aperture_m: float | None = None


@dataclass(frozen=True, slots=True)
class CyclePlan:
    """Every action needed to take one mug from the counter to its tray slot, with predicted cost."""

    mug_id: str
    steps: tuple[Step, ...]
    duration_s: float
    energy_j: float
    # Where the mug's handle will point on the tray (world yaw): the arm has no wrist yaw, so it follows from
    # the handle's yaw on the counter and the grasps. None when the planner does not predict it.
    handle_yaw_rad: float | None = None

    def steps_for(self, state: str) -> tuple[Step, ...]:
        """The steps of one top-level state (``side_grasp``, ``flip`` or ``place``), in order."""
        return tuple(s for s in self.steps if s.phase.split(".", 1)[0] == state)


class MotionRefused(ValueError):
    """No safe motion exists (unreachable target, joint limit, collision); the arm was not commanded.

    ``blockers`` names the mugs (by id, on the counter or the tray) whose presence made the motion
    impossible: the same request is refused again until one of them moves or goes. It is empty when no mug
    is to blame (out of reach, a joint limit, the tray's walls, the counter top)."""

    def __init__(self, message: str, *, blockers: Iterable[str] = ()) -> None:
        super().__init__(message)
        self.blockers = frozenset(blockers)

    @classmethod
    def combining(cls, message: str, causes: Iterable[MotionRefused]) -> MotionRefused:
        """A refusal summing up several (every alternative tried failed): blocked by what blocked any."""
        return cls(message, blockers=frozenset().union(*(c.blockers for c in causes)))


@runtime_checkable
class MotionPlanner(Protocol):
    """Plans the joint motions of a pick-flip-place cycle (``planning.motion.CyclePlanner``)."""

    def plan_cycle(
        self,
        start_q: Sequence[float],
        mug: MugPose,
        slot: TraySlot,
        on_tray: Sequence[TraySlot],
        *,
        counter: Sequence[MugPose] = (),
    ) -> CyclePlan:
        """Raises ``MotionRefused`` with the reason when any part of the cycle is impossible. ``counter``
        lists the other mugs still on the counter, obstacles for the approach and the carry."""
        ...

    def plan_for_slot(
        self,
        start_q: Sequence[float],
        slot: TraySlot,
        counter: Sequence[MugPose],
        on_tray: Sequence[TraySlot],
    ) -> tuple[MugPose, CyclePlan]:
        """The cycle filling ``slot`` with the mug it names or, when that one cannot be moved there, with
        another mug of ``counter`` of the slot's type (the mug used and its plan; the plan's steps name
        it). ``counter`` is every mug on the counter, the candidates and the obstacles. Each candidate is
        planned on its own, so taking a candidate away never makes a refused slot possible; the refusal's
        ``blockers`` are those of every candidate."""
        ...

    def plan_move(self, start_q: Sequence[float], goal_q: Sequence[float], *, label: str) -> JointTrajectory:
        """A joint-space move within the servo limits (used for parking and recovery)."""
        ...
