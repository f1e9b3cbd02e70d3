"""The counter as the job knows it: looking at it (observe, associate, name new mugs, publish the
detections) and leaving a mug on it for good. Used by ``detect``, ``recover_lost_mug`` and ``cycles``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from daemon.job.context import JobContext
from daemon.job.services import Services
from daemon.messages import depth_preview, detections_message
from perception.interfaces import Detection
from planning.interfaces import MugPose
from wire.messages import MugGivenUpEvent

# The context keys these touch, for the declarations of the units that call them.
LOOK_READS = frozenset({"counter"})
LOOK_WRITES = frozenset({"next_id"})
GIVE_UP_WRITES = frozenset({"given_up", "summary"})
# Mugs in one row across the counter stand at one y: their brims (74-91 mm across) keep rows further apart.
_ROW_M = 0.04


async def look(services: Services, ctx: JobContext, *, target_id: str = "") -> dict[str, MugPose]:
    """Observe the counter and give each detection the id of the known mug it is, or a new id; publish the
    detections. ``target_id`` names the mug the arm was handling. Returns the counter by id."""
    obs = await services.backend.observer.observe()
    tray = services.backend.tray
    # Mugs standing on the tray are the job's own work (it knows them); only counter mugs are to load.
    on_counter = tuple(d for d in obs.detections if not tray.contains(d.x_m, d.y_m))
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


def give_up(services: Services, ctx: JobContext, mug_id: str, reason: str) -> None:
    """Leave a mug on the counter for good (it stays known, so it is not mistaken for a new one)."""
    ctx.given_up.add(mug_id)
    ctx.summary.failed = len(ctx.given_up)
    services.event(MugGivenUpEvent(mug_id=mug_id, reason=reason))


def _pose(d: Detection) -> MugPose:
    return MugPose(d.mug_id, d.type, d.x_m, d.y_m, d.handle_yaw_rad, d.upside_down, d.handle_seen)
