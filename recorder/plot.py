"""One picture of a session: a lane per state over time, gripper force, joint angles, events, injected faults.

For people who would rather look than read, and for CI artefacts (``dishbot record plot``). It reads the
JSON channels through ``read_messages``, so a file cut by a crash is drawn up to the cut (and says so in its
title). matplotlib is an optional dependency (``pip install 'dishbot[plot]'``); it is imported only here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Final

from recorder.reader import RecordingRead
from wire.messages import UNSET, Event, Gripper, HeaderFile, Joints, SessionHeader, State, header_part
from wire.schemas import HEADER_TOPIC, topic_suffix

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

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
# A fault a fault file made happen (``replay.faults``): a dashed line through every panel, named.
INJECTED: Final = "fault_injected"
_INJECTED_COLOUR: Final = "#e7298a"
# A state shorter than this share of the time axis (detect and plan take no simulated time; done is the last
# message) is still drawn this wide, so that every state entered shows.
_MIN_SPAN_SHARE: Final = 0.004


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
    injected: list[tuple[float, str]] = field(default_factory=list)  # (t, fault kind) of a fault file
    end_s: float = 0.0

    @classmethod
    def of(cls, rec: RecordingRead) -> SessionSeries:
        s = cls()
        t0 = rec.start_ns or 0
        for m in rec:
            t = (m.log_time_ns - t0) / 1e9
            kind = topic_suffix(m.topic)
            if kind == "state" and (st := m.decoded(State)) is not None:
                state = st.state.split(".", 1)[0]
                if not s.states or s.states[-1][1] != state:
                    s.states.append((t, state))
            elif kind == "gripper" and (g := m.decoded(Gripper)) is not None:
                s.force_t.append(t)
                s.force_n.append(float(g.force_n) if isinstance(g.force_n, int | float) else float("nan"))
                s.aperture_m.append(float(g.aperture_m))
            elif kind == "joints" and (js := m.decoded(Joints)) is not None:
                positions = [float(v) for v in js.position_rad]
                if not s.joint_names:
                    s.joint_names = list(js.names)
                if s.joints and len(positions) != len(s.joints[-1]):
                    continue
                s.joints_t.append(t)
                s.joints.append(positions)
            elif kind == "events" and (e := m.decoded(Event)) is not None:
                mug = e.mug_id if isinstance(e.mug_id, str) else ""
                if e.kind in EVENT_MARKS or e.kind in _DEVICE_FAULTS:
                    s.events.append((t, e.kind, mug))
                elif e.kind == INJECTED:
                    s.injected.append((t, e.fault if isinstance(e.fault, str) and e.fault else "fault"))
        s.end_s = ((rec.end_ns or t0) - t0) / 1e9
        return s


def keep_for_plot(topic: str) -> bool:
    """The topics ``read_messages(keep=...)`` must decode for a plot (and the header, for the title)."""
    return topic_suffix(topic) in ("state", "gripper", "joints", "events", HEADER_TOPIC)


def plot_session(
    rec: RecordingRead, outputs: Sequence[Path], *, title: str | None = None, width_in: float = 12.0
) -> None:
    """Draw the recording and save it to each of ``outputs`` (the format from the suffix: .png, .svg)."""
    fig = session_figure(rec, title=title, width_in=width_in)  # PlotUnavailable without matplotlib
    import matplotlib.pyplot as plt

    try:
        for path in outputs:
            fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)


def session_figure(rec: RecordingRead, *, title: str | None = None, width_in: float = 12.0) -> Figure:
    """The picture of a recording: a lane per state entered (the top lane: the events, injected faults
    named), gripper force and aperture, joint angles; every state and event also marked over the panels."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.lines import Line2D
    except ImportError as e:
        raise PlotUnavailable("plotting needs matplotlib: pip install 'dishbot[plot]'") from e
    s = SessionSeries.of(rec)
    end = max(s.end_s, 1e-3)
    fig, (ax_state, ax_force, ax_joints) = plt.subplots(
        3,
        1,
        figsize=(width_in, 7.5),
        sharex=True,
        gridspec_kw={"height_ratios": [1.7, 2.0, 2.3], "hspace": 0.08},
        layout="constrained",
    )
    lanes = _lanes([state for _, state in s.states])
    row = {state: len(lanes) - 1 - i for i, state in enumerate(lanes)}  # chart order, top down
    events_row = len(lanes)
    min_span = end * _MIN_SPAN_SHARE
    for i, (t, state) in enumerate(s.states):
        stop = s.states[i + 1][0] if i + 1 < len(s.states) else end
        colour = STATE_COLOURS.get(state, "#969696")
        ax_state.broken_barh([(t, max(stop - t, min_span))], (row[state] - 0.4, 0.8), color=colour, lw=0)
        for ax in (ax_force, ax_joints):
            ax.axvspan(t, stop, color=colour, alpha=0.18, lw=0)
    ax_state.set_yticks([*row.values(), events_row], [*row, "events"], fontsize=8)
    ax_state.set_ylim(-0.6, events_row + 0.9)
    ax_state.set_ylabel("state")
    marks_seen: dict[str, tuple[str, str, str]] = {}
    for t, kind, mug in s.events:
        label, colour, marker = EVENT_MARKS.get(kind, ("device fault", "#a50f15", "P"))
        marks_seen.setdefault(label, (label, colour, marker))
        ax_state.plot([t], [events_row], marker=marker, color=colour, ms=7, mec="white", mew=0.6, ls="none")
        if mug and kind != "mug_placed":
            _label(ax_state, t, events_row, mug, end)
        for ax in (ax_force, ax_joints):
            ax.axvline(t, color=colour, lw=0.8, ls=":", alpha=0.9)
    for t, fault in s.injected:
        marks_seen.setdefault("injected fault", ("injected fault", _INJECTED_COLOUR, "*"))
        ax_state.plot([t], [events_row], marker="*", color=_INJECTED_COLOUR, ms=11, mec="white", ls="none")
        _label(ax_state, t, events_row, f"injected {fault}", end, colour=_INJECTED_COLOUR)
        for ax in (ax_state, ax_force, ax_joints):
            ax.axvline(t, color=_INJECTED_COLOUR, lw=1.2, ls="--")
    if marks_seen:
        ax_state.legend(
            handles=[
                Line2D([], [], marker=m, color=c, ls="none", label=label, mec="white")
                for label, c, m in marks_seen.values()
            ],
            loc="lower left",
            bbox_to_anchor=(0.0, 1.02),
            ncol=len(marks_seen),
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
    ax_joints.set_xlim(0.0, end + min_span)  # the last state's minimum width stays inside
    fig.suptitle(title or _title(rec), fontsize=11)
    return fig


def _lanes(states: Sequence[str]) -> list[str]:
    """The states entered, in chart order (those the chart does not list after them)."""
    known = [state for state in STATE_COLOURS if state in states]
    return known + sorted({state for state in states if state not in STATE_COLOURS})


def _label(ax: Axes, t: float, y: float, text: str, end: float, *, colour: str = "black") -> None:
    """A label above a mark, kept inside the axes near either end (it would be cut off there)."""
    ha = "left" if t < 0.08 * end else "right" if t > 0.92 * end else "center"
    ax.annotate(
        text, (t, y), xytext=(0, 6), textcoords="offset points", ha=ha, va="bottom", fontsize=7, color=colour
    )


def _title(rec: RecordingRead) -> str:
    header = next((m.decoded(SessionHeader) for m in rec if m.topic == HEADER_TOPIC), None)
    file = header_part(header.file if header is not None else None, HeaderFile)
    kind = file.kind if file.kind is not UNSET else None
    duration = ((rec.end_ns or 0) - (rec.start_ns or 0)) / 1e9
    text = f"{rec.path.name}{f' ({kind})' if kind else ''}, {duration:.1f} s"
    if rec.being_written:
        text += " - still being written"
    elif rec.truncated:
        text += f" - cut at byte {rec.cut_at_byte} ({rec.cut_reason})"
    return text
