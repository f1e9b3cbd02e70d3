"""What one loading job knows, shared by its units of work: ``JobContext``, one typed object whose fields are
the keys units declare they read and write. Also what a unit ends with (``Outcome``) and the numbers a job
reports (``JobSummary``)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Final

from drivers.interfaces import Clock
from planning.interfaces import CyclePlan, MugPose, TraySlot
from planning.placement import PlanOptions, TrayMug


@dataclass(frozen=True, slots=True)
class Outcome:
    """What a unit's work ended with: the event to fire and its guard values and detail."""

    trigger: str
    values: Mapping[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class JobSummary:
    """The numbers ``dishbot run --once`` prints and ``status`` reports."""

    detected: int = 0
    planned: int = 0
    placed: int = 0
    failed: int = 0
    grasp_failures: int = 0
    drops: int = 0
    recording_dropped: int = 0  # messages the recording lost since the job started (a full disk, say)
    # The last plan's mugs left on the counter, one short line each: out of reach (left out before packing)
    # or their slot dropped (no order lets the arm fill it).
    left_out: list[str] = field(default_factory=list)
    started_at: float | None = None
    ended_at: float | None = None
    end_state: str = ""
    clock: Clock | None = field(default=None, repr=False, compare=False)  # what started_at was read on

    @property
    def duration_s(self) -> float:
        if self.started_at is None:
            return 0.0
        if self.ended_at is not None:
            return self.ended_at - self.started_at
        return 0.0 if self.clock is None else self.clock.monotonic() - self.started_at

    def to_json(self) -> dict[str, object]:
        return {
            "detected": self.detected,
            "planned": self.planned,
            "placed": self.placed,
            "failed": self.failed,
            "grasp_failures": self.grasp_failures,
            "drops": self.drops,
            "recording_dropped": self.recording_dropped,
            "left_out": list(self.left_out),
            "duration_s": round(self.duration_s, 3),
            "end_state": self.end_state,
        }


@dataclass(frozen=True, slots=True)
class Deferral:
    """Why a queued slot could not be planned, as far as it can change: the mugs the refusal named
    (``MotionRefused.blockers``) as they stood then (None: not on the counter, i.e. on the tray), and the
    counter mugs it could have been filled with. Trying again can only succeed once a blocker moved or
    went, or a candidate moved or came; taking a candidate away cannot help (each is planned on its own).
    Where the arm starts from is not part of it: an approach that would sweep through a mug from there
    rises to carry height first (``CyclePlanner``), so the start does not decide whether a slot can be
    reached."""

    blockers: tuple[tuple[str, MugPose | None], ...]
    candidates: tuple[MugPose, ...]

    @classmethod
    def of(cls, blockers: Iterable[str], counter: Mapping[str, MugPose], slot: TraySlot) -> Deferral:
        return cls(
            tuple((b, counter.get(b)) for b in sorted(blockers)), tuple(_candidates_for(slot, counter))
        )

    def still_blocked(self, counter: Mapping[str, MugPose], slot: TraySlot) -> bool:
        """Whether nothing the refusal depended on changed, so planning again would be refused again."""
        tried = {m.mug_id: m for m in self.candidates}
        return all(_stands_as(counter.get(b), then) for b, then in self.blockers) and all(
            _stands_as(m, tried.get(m.mug_id)) for m in _candidates_for(slot, counter)
        )


def _candidates_for(slot: TraySlot, counter: Mapping[str, MugPose]) -> Iterable[MugPose]:
    """The counter mugs a slot may be filled with: its own and those of its type (``plan_for_slot``)."""
    return (m for m in counter.values() if m.type == slot.type or m.mug_id == slot.mug_id)


# A mug whose handle is seen turned by less than this has not been turned: the detectors' handle direction
# jitters by a few degrees from one look to the next (the association keeps a mug's position, not its yaw).
_SAME_HANDLE_RAD = math.radians(10.0)


def _stands_as(now: MugPose | None, then: MugPose | None) -> bool:
    """Whether a mug (None: not on the counter) stands as it stood, up to the jitter of its handle's yaw."""
    if now is None or then is None:
        return now is then
    turned = abs(math.remainder(now.handle_yaw_rad - then.handle_yaw_rad, math.tau))
    return replace(now, handle_yaw_rad=then.handle_yaw_rad) == then and turned < _SAME_HANDLE_RAD


@dataclass(slots=True)
class JobContext:
    """Everything one loading job knows. Units name the fields they use (``Unit.reads``, ``Unit.writes``)."""

    planner: PlanOptions  # placement preferences of this job
    counter: dict[str, MugPose] = field(default_factory=dict)  # the mugs seen on the counter, by id
    given_up: set[str] = field(default_factory=set)  # mugs left on the counter for good
    attempts: dict[str, int] = field(default_factory=dict)  # recoveries per mug
    on_tray: list[TraySlot] = field(default_factory=list)  # where the placed mugs stand
    tray_mugs: list[TrayMug] = field(default_factory=list)  # the same, as the placement planner takes them
    # Mugs lying on the tray where no slot of the job is (one that fell there on the way): obstacles for every
    # later slot and cycle, never picked (``counter.look`` finds them; they stay for the job).
    strays: list[MugPose] = field(default_factory=list)
    queue: list[tuple[TraySlot, TrayMug]] = field(default_factory=list)  # planned slots still to fill
    deferred: dict[TraySlot, Deferral] = field(default_factory=dict)  # queued slots no motion reached
    needs_plan: bool = True  # the counter changed since the placement was planned
    current: TraySlot | None = None  # the slot of the mug being handled
    current_tray_mug: TrayMug | None = None
    cycle: CyclePlan | None = None  # the current mug's pick-flip-place plan
    step: int = 0  # the index of the cycle's next step
    carrying: bool = False  # the gripper should hold the mug (the force sensor is watched)
    grasp_held: bool = False  # the last close reported a hold
    rejoin: bool = False  # resumed after a pause: join the interrupted move where the arm is
    next_id: int = 1  # for the next new mug's id
    summary: JobSummary = field(default_factory=JobSummary)

    def next_job(self, planner: PlanOptions) -> JobContext:
        """The context of a job that follows this one on the same scene (after a stop, or an estop and a
        reset): the mugs on the tray stay (placed or stray), the mugs known on the counter keep their ids
        (its first look finds them where they were), and only mugs new to the counter get new ids."""
        return JobContext(
            planner=planner,
            counter=dict(self.counter),
            on_tray=list(self.on_tray),
            tray_mugs=list(self.tray_mugs),
            strays=list(self.strays),
            next_id=self.next_id,
        )


KEYS: Final = frozenset(f.name for f in dataclasses.fields(JobContext))
