"""One picture of a session: the states as coloured bands over time, gripper force, joint angles, events.

For people who would rather look than read, and for CI artefacts (``dishbot record plot``). It reads the
JSON channels through ``read_messages``, so a file cut by a crash is drawn up to the cut (and says so in its
title). matplotlib is an optional dependency (``pip install 'dishbot[plot]'``); it is imported only here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from recorder.reader import RecordingRead
from wire.schemas import HEADER_TOPIC, topic_suffix

# Top-level states in chart order and the colour of their band.
STATE_COLOURS: Final = {
    "idle": "#d9d9d9",
    "detect": "#9ecae1",
    "plan": "#c6dbef",
    "side_grasp": "#fdae6b",
    "flip": "#fdd0a2",
    "place": "#a1d99b",
    "recover_lost_mug": "#fc9272",
    "paused": "#bcbddc",
    "fault": "#de2d26",
    "estop": "#67000d",
    "done": "#31a354",
}
# The events marked on the time axis: kind -> (label, colour, marker).
EVENT_MARKS: Final = {
    "mug_placed": ("placed", "#238b45", "v"),
    "mug_dropped": ("dropped", "#e6550d", "X"),
    "grasp_failed": ("grasp failed", "#756bb1", "x"),
    "mug_given_up": ("given up", "#252525", "s"),
    "fault": ("fault", "#cb181d", "D"),
    "tray_collision": ("tray collision", "#fb6a4a", "*"),
}
_DEVICE_FAULTS: Final = ("servo_fault", "bus_lost", "fsr_lost", "fsr_stale")


class PlotUnavailable(RuntimeError):
    """matplotlib is not installed."""


@dataclass(slots=True)
class SessionSeries:
    """The time series of one recording, in seconds from its first message."""

    states: list[tuple[float, str]] = field(default_factory=list)
    force_t: list[float] = field(default_factory=list)
    force_n: list[float] = field(default_factory=list)
    aperture_m: list[float] = field(default_factory=list)
    joints_t: list[float] = field(default_factory=list)
    joints: list[list[float]] = field(default_factory=list)
    joint_names: list[str] = field(default_factory=list)
    events: list[tuple[float, str, str]] = field(default_factory=list)  # (t, kind, mug id)
    end_s: float = 0.0

    @classmethod
    def of(cls, rec: RecordingRead) -> SessionSeries:
        s = cls()
        t0 = rec.start_ns or 0
        for m in rec:
            t = (m.log_time_ns - t0) / 1e9
            kind = topic_suffix(m.topic)
            p = m.payload
            if kind == "state" and isinstance(p.get("state"), str):
                state = str(p["state"]).split(".", 1)[0]
                if not s.states or s.states[-1][1] != state:
                    s.states.append((t, state))
            elif kind == "gripper":
                force = p.get("force_n")
                aperture = p.get("aperture_m")
                s.force_t.append(t)
                s.force_n.append(float(force) if isinstance(force, int | float) else float("nan"))
                s.aperture_m.append(float(aperture) if isinstance(aperture, int | float) else float("nan"))
            elif kind == "joints" and isinstance(q := p.get("position_rad"), list):
                positions = [float(v) for v in q]
                if not s.joint_names and isinstance(names := p.get("names"), list):
                    s.joint_names = [str(n) for n in names]
                if s.joints and len(positions) != len(s.joints[-1]):
                    continue
                s.joints_t.append(t)
                s.joints.append(positions)
            elif kind == "events":
                event = str(p.get("kind", ""))
                if event in EVENT_MARKS or event in _DEVICE_FAULTS:
                    s.events.append((t, event, str(p.get("mug_id") or "")))
        s.end_s = ((rec.end_ns or t0) - t0) / 1e9
        return s


def keep_for_plot(topic: str) -> bool:
    """The topics ``read_messages(keep=...)`` must decode for a plot (and the header, for the title)."""
    return topic_suffix(topic) in ("state", "gripper", "joints", "events", HEADER_TOPIC)


def plot_session(
    rec: RecordingRead, outputs: Sequence[Path], *, title: str | None = None, width_in: float = 12.0
) -> None:
    """Draw the recording and save it to each of ``outputs`` (the format from the suffix: .png, .svg)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch
    except ImportError as e:
        raise PlotUnavailable("plotting needs matplotlib: pip install 'dishbot[plot]'") from e
    s = SessionSeries.of(rec)
    end = max(s.end_s, 1e-3)
    fig, (ax_state, ax_force, ax_joints) = plt.subplots(
        3,
        1,
        figsize=(width_in, 7.5),
        sharex=True,
        gridspec_kw={"height_ratios": [1.0, 2.0, 2.6], "hspace": 0.08},
        layout="constrained",
    )
    seen_states: list[str] = []
    for i, (t, state) in enumerate(s.states):
        stop = s.states[i + 1][0] if i + 1 < len(s.states) else end
        colour = STATE_COLOURS.get(state, "#969696")
        for ax in (ax_state, ax_force, ax_joints):
            ax.axvspan(t, stop, color=colour, alpha=1.0 if ax is ax_state else 0.18, lw=0)
        if state not in seen_states:
            seen_states.append(state)
    ax_state.set_yticks([])
    ax_state.set_ylim(0, 1)
    ax_state.set_ylabel("state", rotation=0, ha="right", va="center")
    marks_seen: dict[str, tuple[str, str, str]] = {}
    for t, kind, mug in s.events:
        label, colour, marker = EVENT_MARKS.get(kind, ("device fault", "#a50f15", "P"))
        marks_seen.setdefault(label, (label, colour, marker))
        ax_state.plot([t], [0.5], marker=marker, color=colour, ms=8, mec="white", mew=0.6, ls="none")
        if mug and kind != "mug_placed":
            ax_state.annotate(
                mug, (t, 0.5), xytext=(0, 7), textcoords="offset points", ha="center", fontsize=7
            )
        for ax in (ax_force, ax_joints):
            ax.axvline(t, color=colour, lw=0.8, ls=":", alpha=0.9)
    handles: list[Patch | Line2D] = [
        Patch(color=STATE_COLOURS.get(st, "#969696"), label=st) for st in seen_states
    ]
    handles += [
        Line2D([], [], marker=m, color=c, ls="none", label=label, mec="white")
        for label, c, m in marks_seen.values()
    ]
    if handles:
        ax_state.legend(
            handles=handles,
            loc="lower left",
            bbox_to_anchor=(0.0, 1.02),
            ncol=min(len(handles), 8),
            fontsize=8,
        )
    if s.force_t:
        ax_force.plot(s.force_t, s.force_n, color="#08519c", lw=1.0, label="FSR force")
        twin = ax_force.twinx()
        twin.plot(s.force_t, [a * 1000.0 for a in s.aperture_m], color="#636363", lw=0.8, alpha=0.7)
        twin.set_ylabel("aperture (mm)", color="#636363")
        twin.tick_params(axis="y", colors="#636363")
    else:
        ax_force.text(0.5, 0.5, "no gripper samples", transform=ax_force.transAxes, ha="center", va="center")
    ax_force.set_ylabel("gripper force (N)", color="#08519c")
    if s.joints_t:
        columns = list(zip(*s.joints, strict=True))
        for i, column in enumerate(columns):
            name = s.joint_names[i] if i < len(s.joint_names) else f"joint {i + 1}"
            ax_joints.plot(s.joints_t, column, lw=1.0, label=name)
        ax_joints.legend(
            loc="upper center", bbox_to_anchor=(0.5, -0.16), fontsize=8, ncol=len(columns), frameon=False
        )
    else:
        ax_joints.text(0.5, 0.5, "no joint samples", transform=ax_joints.transAxes, ha="center", va="center")
    ax_joints.set_ylabel("joint angle (rad)")
    ax_joints.set_xlabel("time since the first message (s)")
    ax_joints.set_xlim(0.0, end)
    fig.suptitle(title or _title(rec), fontsize=11)
    try:
        for path in outputs:
            fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)


def _title(rec: RecordingRead) -> str:
    header = rec.header or {}
    file = header.get("file")
    kind = file.get("kind") if isinstance(file, dict) else None
    duration = ((rec.end_ns or 0) - (rec.start_ns or 0)) / 1e9
    text = f"{rec.path.name}{f' ({kind})' if kind else ''}, {duration:.1f} s"
    if rec.being_written:
        text += " - still being written"
    elif rec.truncated:
        text += f" - cut at byte {rec.cut_at_byte} ({rec.cut_reason})"
    return text
