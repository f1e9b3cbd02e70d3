"""``dishbot record info|plot FILE``: what a recording holds, how its job went, and a picture of it."""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from cli.commands.output import add_json_flag, format_table
from daemon.errors import UsageError
from recorder.errors import RecordingError

if TYPE_CHECKING:
    from recorder import RecordingRead
    from recorder.outcome import JobOutcome
    from wire.messages import UnsetType

T = TypeVar("T")

# Log times from 2000-01-01 on are wall-clock (Unix epoch) stamps; earlier ones come from a session clock.
_EPOCH_FLOOR_NS = 946_684_800 * 10**9


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "record",
        help="inspect session recordings (MCAP): summary and outcome, or a picture",
        description="Inspect the MCAP files the daemon records: one per job, idle time in rotating files.",
    )
    verbs = parser.add_subparsers(dest="record_verb", metavar="VERB", required=True)
    info = verbs.add_parser(
        "info",
        help="summarise a recording: status, what the job ran and how it went, messages per topic",
        description=(
            "Summarise one recording: whether it is finished, still being written by a running daemon, or "
            "cut by a crash (and where); what its job ran (dataset or mugs, planner settings, seeds) and "
            "how it went (mugs placed, mugs given up with their reasons, faults); start, end and duration; "
            "messages per topic with their schema. A cut file is read up to the cut."
        ),
    )
    info.add_argument("file", type=Path, metavar="FILE", help="the .mcap file to summarise")
    add_json_flag(info)
    info.set_defaults(handler=run_info)
    plot = verbs.add_parser(
        "plot",
        help="draw a recording: states as coloured bands, gripper force, joint angles, events",
        description=(
            "Draw one picture of a recording: the states as coloured bands on a time axis, the gripper "
            "force and aperture, the joint angles, and the events marked (placements, drops, failed "
            "grasps, mugs given up, faults). Works on a file cut by a crash. Needs matplotlib "
            "(pip install 'dishbot[plot]')."
        ),
    )
    plot.add_argument("file", type=Path, metavar="FILE", help="the .mcap file to draw")
    plot.add_argument("--png", type=Path, metavar="OUT", help="write the picture as PNG")
    plot.add_argument("--svg", type=Path, metavar="OUT", help="write the picture as SVG")
    plot.set_defaults(handler=run_plot)


def run_info(args: argparse.Namespace) -> int:
    from recorder import HEADER_TOPIC, read_messages
    from wire.schemas import topic_suffix

    try:
        rec = read_messages(
            args.file, keep=lambda topic: topic == HEADER_TOPIC or topic_suffix(topic) == "events"
        )
    except RecordingError as e:
        raise UsageError(str(e)) from e
    summary = RecordingSummary.of(rec)
    if args.json:
        json.dump(summary.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(summary.render())
    return 0


def run_plot(args: argparse.Namespace) -> int:
    outputs = [(flag, path) for flag, path in (("--png", args.png), ("--svg", args.svg)) if path is not None]
    if not outputs:
        raise UsageError("give --png OUT and/or --svg OUT")
    for flag, path in outputs:
        if path.suffix.lower() != f".{flag[2:]}":
            raise UsageError(f"{flag} {path}: the file name must end in .{flag[2:]}")
        if not path.parent.resolve().is_dir():
            raise UsageError(f"{flag} {path}: directory {str(path.parent)!r} does not exist")
    from recorder import read_messages
    from recorder.plot import PlotUnavailable, keep_for_plot, plot_session

    try:
        rec = read_messages(args.file, keep=keep_for_plot)
    except RecordingError as e:
        raise UsageError(str(e)) from e
    start = time.perf_counter()
    try:
        plot_session(rec, [path for _, path in outputs])
    except PlotUnavailable as e:
        raise UsageError(str(e)) from e
    except OSError as e:
        raise UsageError(f"cannot write the picture: {e.strerror}") from e
    for _, path in outputs:
        print(f"wrote {path} ({time.perf_counter() - start:.2f} s)")
    return 0


@dataclass(frozen=True, slots=True)
class RecordingSummary:
    """The facts ``record info`` prints about one recording."""

    path: str
    size_bytes: int
    finished: bool
    being_written: bool
    truncated: bool
    cut_at_byte: int | None
    cut_after_s: float | None  # seconds from the first message to the last one recovered before the cut
    cut_reason: str
    messages: int
    kind: str | None  # "job", "idle", or None for files without a file header
    robot_id: object
    dataset: object
    mugs: object
    planner: object
    sim_seed: object
    writer_pid: object
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    topics: dict[str, int]
    schemas: dict[str, str]
    outcome: JobOutcome | None = None
    previous: object = None
    extra: dict[str, object] = field(default_factory=dict)

    @classmethod
    def of(cls, rec: RecordingRead) -> RecordingSummary:
        from recorder.outcome import JobOutcome
        from wire.messages import (
            UNSET,
            Event,
            HeaderConfig,
            HeaderFile,
            HeaderJob,
            HeaderScene,
            SessionHeader,
            header_part,
        )
        from wire.schemas import HEADER_TOPIC, topic_suffix

        header = next((m.decoded(SessionHeader) for m in rec if m.topic == HEADER_TOPIC), None)
        if header is None:
            header = SessionHeader(config={}, scene={})
        config = header_part(header.config, HeaderConfig)
        scene = header_part(header.scene, HeaderScene)
        job = header_part(header.job, HeaderJob)
        file = header_part(header.file, HeaderFile)
        start, end = rec.start_ns, rec.end_ns
        cut_after_s = None
        if rec.cut_after_ns is not None and start is not None:
            cut_after_s = round((rec.cut_after_ns - start) / 1e9, 3)
        events = [e for m in rec if topic_suffix(m.topic) == "events" and (e := m.decoded(Event)) is not None]
        kind = _given(file.kind)
        outcome = JobOutcome.of(events) if kind == "job" or (kind is None and events) else None
        mugs = _given(job.mugs)
        dataset = job.dataset if job.dataset is not UNSET else _given(scene.dataset, _given(config.dataset))
        return cls(
            path=str(rec.path),
            size_bytes=rec.size_bytes,
            finished=not rec.truncated,
            being_written=rec.being_written,
            truncated=rec.truncated,
            cut_at_byte=rec.cut_at_byte,
            cut_after_s=cut_after_s,
            cut_reason=rec.cut_reason,
            messages=rec.message_count,
            kind=str(kind) if kind is not None else None,
            robot_id=_given(config.robot_id),
            dataset=dataset,
            mugs=None if mugs is None else [_given(m.id) for m in mugs],
            planner=_given(job.planner),
            sim_seed=_given(job.sim_seed),
            writer_pid=_given(file.pid),
            start_ns=start,
            end_ns=end,
            duration_s=round((end - start) / 1e9, 3) if start is not None and end is not None else 0.0,
            topics=dict(sorted(rec.topic_counts.items())),
            schemas=dict(sorted(rec.schema_names.items())),
            outcome=outcome,
            previous=_given(file.previous),
        )

    @property
    def status(self) -> str:
        if self.finished:
            return "finished"
        if self.being_written:
            who = f" (pid {self.writer_pid})" if self.writer_pid is not None else ""
            return f"being written by a running recorder{who}; {self.messages} messages so far"
        return (
            f"cut by a crash or a partial copy at byte {self.cut_at_byte} "
            f"(after {self.cut_after_s or 0.0:.3f} s); {self.messages} messages recovered ({self.cut_reason})"
        )

    def to_json(self) -> dict[str, object]:
        doc: dict[str, object] = {f: getattr(self, f) for f in self.__dataclass_fields__ if f != "extra"}
        doc["outcome"] = None if self.outcome is None else self.outcome.to_json()
        doc["status"] = self.status
        doc["start"] = _time_text(self.start_ns)
        doc["end"] = _time_text(self.end_ns)
        return doc

    def render(self) -> str:
        lines = [
            f"file:      {self.path} ({self.size_bytes} bytes)",
            f"status:    {self.status}",
            f"kind:      {_or_dash(self.kind)}",
            f"robot id:  {_or_dash(self.robot_id)}",
        ]
        if isinstance(self.mugs, list):
            lines.append(f"mugs:      {len(self.mugs)} given: {' '.join(str(m) for m in self.mugs)}")
        else:
            lines.append(f"dataset:   {_or_dash(self.dataset)}")
        if isinstance(self.planner, dict):
            from wire.messages import HeaderPlanner, header_part

            p = header_part(self.planner, HeaderPlanner)
            lines.append(
                f"planner:   {_given(p.method)}, cost {_given(p.cost)}, fitness {_given(p.fitness)}, "
                f"time limit {_given(p.time_limit_s)} s, seed {_given(p.seed)}"
            )
        if self.sim_seed is not None:
            lines.append(f"sim seed:  {self.sim_seed}")
        lines += [
            f"start:     {_or_dash(_time_text(self.start_ns))}",
            f"end:       {_or_dash(_time_text(self.end_ns))}",
            f"duration:  {self.duration_s:.3f} s",
            f"messages:  {self.messages}",
        ]
        if self.outcome is not None:
            lines += ["", *_outcome_lines(self.outcome)]
        if self.topics:
            rows = [(t, self.schemas.get(t, "-"), n) for t, n in self.topics.items()]
            lines += ["", format_table(("topic", "schema", "messages"), rows)]
        return "\n".join(lines)


def _outcome_lines(outcome: JobOutcome) -> list[str]:
    placed, given_up = outcome.placed, outcome.given_up
    lines = [
        f"outcome:   {outcome.end_state or 'not ended in this file'}",
        f"placed:    {len(placed)}{': ' + ' '.join(map(str, placed)) if placed else ''}",
        f"given up:  {len(given_up)}",
    ]
    lines += [f"  {mug_id}: {reason}" for mug_id, reason in given_up.items()]
    for name, counts in (("grasp failures", outcome.grasp_failures), ("drops", outcome.drops)):
        if counts:
            lines.append(f"{name}: " + ", ".join(f"{m} ×{n}" for m, n in counts.items()))
    faults, device = outcome.faults, outcome.device_faults
    lines.append(f"faults:    {len(faults)}")
    lines += [f"  {f}" for f in faults]
    if device:
        lines.append(f"device faults: {len(device)}")
        lines += [f"  {d}" for d in device]
    return lines


def _given(value: T | UnsetType, default: T | None = None) -> T | None:
    """A view's field, ``default`` when the document leaves it out."""
    from wire.messages import UnsetType

    return default if isinstance(value, UnsetType) else value


def _time_text(ns: int | None) -> str | None:
    if ns is None:
        return None
    if ns >= _EPOCH_FLOOR_NS:
        stamp = datetime.fromtimestamp(ns / 1e9, tz=UTC)
        return stamp.isoformat(timespec="milliseconds").replace("+00:00", "Z")
    return f"t={ns / 1e9:.3f} s (session clock)"


def _or_dash(value: object) -> str:
    return "-" if value is None else str(value)
