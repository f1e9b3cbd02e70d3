"""``dishbot record info FILE``: what a session recording holds, and where a cut one ends."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.commands.output import add_json_flag, format_table
from daemon.errors import RecordingError, UsageError

if TYPE_CHECKING:
    from daemon.recording import RecordingRead

# Log times from 2000-01-01 on are wall-clock (Unix epoch) stamps; earlier ones come from a session clock.
_EPOCH_FLOOR_NS = 946_684_800 * 10**9


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "record",
        help="inspect session recordings (MCAP)",
        description="Inspect the MCAP files the daemon records, one per session.",
    )
    verbs = parser.add_subparsers(dest="record_verb", metavar="VERB", required=True)
    info = verbs.add_parser(
        "info",
        help="summarise a recording: time span, messages per topic, robot id and dataset",
        description=(
            "Summarise one recording: start, end and duration, messages per topic, and the robot id and "
            "dataset from the session header. A file whose writer never finished (crash, kill -9, partial "
            "copy) is read up to the cut, and the summary says where it was cut."
        ),
    )
    info.add_argument("file", type=Path, metavar="FILE", help="the .mcap file to summarise")
    add_json_flag(info)
    info.set_defaults(handler=run_info)


def run_info(args: argparse.Namespace) -> int:
    from daemon.recording import HEADER_TOPIC, read_messages

    try:
        rec = read_messages(args.file, keep=lambda topic: topic == HEADER_TOPIC)
    except RecordingError as e:
        raise UsageError(str(e)) from e
    summary = RecordingSummary.of(rec)
    if args.json:
        json.dump(summary.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(summary.render())
    return 0


@dataclass(frozen=True, slots=True)
class RecordingSummary:
    """The facts ``record info`` prints about one recording."""

    path: str
    size_bytes: int
    truncated: bool
    cut_at_byte: int | None
    cut_after_s: float | None  # seconds from the first message to the last one recovered before the cut
    cut_reason: str
    messages: int
    robot_id: object
    dataset: object
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    topics: dict[str, int]

    @classmethod
    def of(cls, rec: RecordingRead) -> RecordingSummary:
        header = rec.header or {}
        config = header.get("config")
        scene = header.get("scene")
        config = config if isinstance(config, dict) else {}
        scene = scene if isinstance(scene, dict) else {}
        start, end = rec.start_ns, rec.end_ns
        cut_after_s = None
        if rec.cut_after_ns is not None and start is not None:
            cut_after_s = round((rec.cut_after_ns - start) / 1e9, 3)
        return cls(
            path=str(rec.path),
            size_bytes=rec.size_bytes,
            truncated=rec.truncated,
            cut_at_byte=rec.cut_at_byte,
            cut_after_s=cut_after_s,
            cut_reason=rec.cut_reason,
            messages=rec.message_count,
            robot_id=config.get("robot_id"),
            dataset=scene.get("dataset", config.get("dataset")),
            start_ns=start,
            end_ns=end,
            duration_s=round((end - start) / 1e9, 3) if start is not None and end is not None else 0.0,
            topics=dict(sorted(rec.topic_counts.items())),
        )

    @property
    def status(self) -> str:
        if not self.truncated:
            return "finished"
        return (
            f"truncated at byte {self.cut_at_byte} (after {self.cut_after_s or 0.0:.3f} s); "
            f"{self.messages} messages recovered ({self.cut_reason})"
        )

    def to_json(self) -> dict[str, object]:
        doc: dict[str, object] = {f: getattr(self, f) for f in self.__dataclass_fields__}
        doc["status"] = self.status
        doc["start"] = _time_text(self.start_ns)
        doc["end"] = _time_text(self.end_ns)
        return doc

    def render(self) -> str:
        lines = [
            f"file:      {self.path} ({self.size_bytes} bytes)",
            f"status:    {self.status}",
            f"robot id:  {_or_dash(self.robot_id)}",
            f"dataset:   {_or_dash(self.dataset)}",
            f"start:     {_or_dash(_time_text(self.start_ns))}",
            f"end:       {_or_dash(_time_text(self.end_ns))}",
            f"duration:  {self.duration_s:.3f} s",
            f"messages:  {self.messages}",
        ]
        if self.topics:
            lines += ["", format_table(("topic", "messages"), list(self.topics.items()))]
        return "\n".join(lines)


def _time_text(ns: int | None) -> str | None:
    if ns is None:
        return None
    if ns >= _EPOCH_FLOOR_NS:
        stamp = datetime.fromtimestamp(ns / 1e9, tz=UTC)
        return stamp.isoformat(timespec="milliseconds").replace("+00:00", "Z")
    return f"t={ns / 1e9:.3f} s (session clock)"


def _or_dash(value: object) -> str:
    return "-" if value is None else str(value)
