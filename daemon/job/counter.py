"""The counter as the job knows it: looking at it (observe, associate, name new mugs, publish the
detections) and leaving a mug on it for good. Used by ``detect``, ``recover_lost_mug`` and ``cycles``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from daemon.job.context import JobContext
from daemon.job.services import Services
from daemon.messages import depth_preview, detections_message
from perception.interfaces import Detection
from planning.interfaces import MugPose, TraySlot
from wire.messages import MugGivenUpEvent

# The context keys these touch, for the declarations of the units that call them.
LOOK_READS = frozenset({"counter", "on_tray", "strays"})
LOOK_WRITES = frozenset({"next_id", "strays"})
GIVE_UP_WRITES = frozenset({"given_up", "summary"})
# Mugs in one row across the counter stand at one y: their brims (74-91 mm across) keep rows further apart.
_ROW_M = 0.04
# A mug seen on the tray this close to one of the job's slots (its brim centre; brims are 74-91 mm across) is
# the mug the job placed there; one farther from every slot lies where no plan put it (``JobContext.strays``).
# The same distance keeps a stray's id from one look to the next.
_SAME_SPOT_M = 0.03


async def look(services: Services, ctx: JobContext, *, target_id: str = "") -> dict[str, MugPose]:
    """Observe the counter and give each detection the id of the known mug it is, or a new id; publish the
    detections. ``target_id`` names the mug the arm was handling. Returns the counter by id."""
    obs = await services.backend.observer.observe()
    tray = services.backend.tray
    # Mugs standing on the tray are the job's own work (it knows them); only counter mugs are to load. A mug
    # on the tray away from every slot of the job fell there: it stays where it is, as an obstacle.
    on_counter = tuple(d for d in obs.detections if not tray.contains(d.x_m, d.y_m))
    on_tray = [d for d in obs.detections if tray.contains(d.x_m, d.y_m)]
    known = [
        Detection(m.type, m.x_m, m.y_m, m.upside_down, m.handle_yaw_rad, 1.0, m.mug_id, m.handle_seen)
        for m in ctx.counter.values()
    ]
    associated = (
        list(services.associate(known, on_counter, target_id=target_id)) if known else list(on_counter)
    )
    seen = sorted((d for d in associated if d.mug_id), key=lambda d: (-d.x_m, d.y_m))
    for d in reading_order([d for d in associated if not d.mug_id]):
        seen.append(replace(d, mug_id=f"m{ctx.next_id}"))
        ctx.next_id += 1
    vanished = target_id if target_id and all(d.mug_id != target_id for d in seen) else ""
    ctx.strays = _strays(ctx, on_tray, vanished)
    preview = None if obs.depth_preview is None else depth_preview(obs.depth_preview)
    services.publish(
        "detections",
        detections_message(
            replace(obs, detections=tuple(seen)), t=services.wall_time(), depth_preview=preview
        ),
    )
    return {d.mug_id: _pose(d) for d in seen}


def reading_order(detections: Sequence[Detection]) -> list[Detection]:
    """New mugs in the order they are named: rows across the counter from the tray's side (small y first),
    each row from the arm's end (large x) first, the order a simulated dataset lists its mugs in, so that
    the world's m3 is the detector's m3. Mugs less than ``_ROW_M`` apart in y, one after the other, stand
    in one row: the detector's few millimetres of noise never reorder a row."""
    rows: list[list[Detection]] = []
    for d in sorted(detections, key=lambda d: d.y_m):
        if rows and d.y_m - rows[-1][-1].y_m < _ROW_M:
            rows[-1].append(d)
        else:
            rows.append([d])
    return [d for row in rows for d in sorted(row, key=lambda d: -d.x_m)]


def _strays(ctx: JobContext, on_tray: Sequence[Detection], vanished: str) -> list[MugPose]:
    """The strays after a look: those known before, where this look sees them again (a look may miss a mug
    on the tray, which does not leave it by itself: an unseen stray stays where it was), and each mug seen on
    the tray away from every slot of the job and every known stray, named ``vanished`` (the mug the arm was
    handling, gone from the counter: it fell there) or as a new mug."""
    strays = {m.mug_id: m for m in ctx.strays}
    for d in sorted(on_tray, key=lambda d: (-d.x_m, d.y_m)):
        if any(_near(d, s.x_m, s.y_m) for s in ctx.on_tray):
            continue
        before = [m.mug_id for m in ctx.strays if _near(d, m.x_m, m.y_m)]
        if before:
            mug_id = before[0]
        elif vanished:
            mug_id, vanished = vanished, ""
        else:
            mug_id = f"m{ctx.next_id}"
            ctx.next_id += 1
        strays[mug_id] = _pose(replace(d, mug_id=mug_id))
    return list(strays.values())


def _near(d: Detection, x_m: float, y_m: float) -> bool:
    return (d.x_m - x_m) ** 2 + (d.y_m - y_m) ** 2 < _SAME_SPOT_M**2


def tray_obstacles(ctx: JobContext) -> tuple[TraySlot, ...]:
    """What stands on the tray for the motion planner: the placed mugs, then the strays where they lie."""
    strays = tuple(
        TraySlot(m.mug_id, m.type, m.x_m, m.y_m, handle_yaw_rad=m.handle_yaw_rad if m.handle_seen else None)
        for m in ctx.strays
    )
    return (*ctx.on_tray, *strays)


def give_up(services: Services, ctx: JobContext, mug_id: str, reason: str) -> None:
    """Leave a mug on the counter for good (it stays known, so it is not mistaken for a new one)."""
    ctx.given_up.add(mug_id)
    ctx.summary.failed = len(ctx.given_up)
    services.event(MugGivenUpEvent(mug_id=mug_id, reason=reason))


def _pose(d: Detection) -> MugPose:
    return MugPose(d.mug_id, d.type, d.x_m, d.y_m, d.handle_yaw_rad, d.upside_down, d.handle_seen)
