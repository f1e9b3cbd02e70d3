"""``dishbot record plot``: one picture of a session, also of one cut by a crash; bad requests: one line."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import pytest
from matplotlib.collections import PolyCollection

from cli.main import main
from recorder import Recorder, read_messages
from recorder.plot import SessionSeries, session_figure

T0 = 1_790_000_000_000_000_000


def session(path: Path, *, seconds: float = 6.0) -> Path:
    """A job as the daemon records it: state changes, gripper and joints at 50 Hz, events."""
    states = [
        "idle",
        "detect",
        "plan",
        "side_grasp.approach",
        "side_grasp.lift",
        "flip.turn",
        "place.release",
    ]
    with Recorder(path, chunk_size=2048) as rec:
        rec.write_header({"robot_id": "r1"}, {}, log_time_ns=T0, file={"kind": "job", "pid": 1})
        n = round(seconds * 50)
        for i in range(n):
            t = T0 + i * 20_000_000
            if i % (n // len(states)) == 0:
                state = states[min(i // (n // len(states)), len(states) - 1)]
                rec.write(
                    "dishbot/r1/state",
                    {"state": state, "mugs_total": 1, "mugs_placed": 0, "t": 0.0},
                    log_time_ns=t,
                )
            held = n // 2 < i < 3 * n // 4
            rec.write(
                "dishbot/r1/gripper",
                {
                    "t": 0.0,
                    "aperture_m": 0.07 if held else 0.12,
                    "force_n": 3.0 if held else 0.0,
                    "holding": held,
                },
                log_time_ns=t,
            )
            rec.write(
                "dishbot/r1/joints",
                {"t": 0.0, "names": ["a", "b"], "position_rad": [0.01 * i, -0.5]},
                log_time_ns=t,
            )
            if i == n // 3:
                rec.write(
                    "dishbot/r1/events", {"kind": "grasp_failed", "mug_id": "m1", "state": "x"}, log_time_ns=t
                )
            if i == 2 * n // 3:
                rec.write(
                    "dishbot/r1/events", {"kind": "mug_dropped", "mug_id": "m1", "state": "y"}, log_time_ns=t
                )
            if i == n - 10:
                rec.write("dishbot/r1/events", {"kind": "mug_placed", "mug_id": "m1"}, log_time_ns=t)
    return path


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


@pytest.mark.slow
def test_plot_writes_png_and_svg_of_a_session(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = session(tmp_path / "job.mcap")
    png, svg = tmp_path / "job.png", tmp_path / "job.svg"
    capsys.readouterr()
    assert main(["record", "plot", str(path), "--png", str(png), "--svg", str(svg)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(" (")[0] for line in out] == [f"wrote {png}", f"wrote {svg}"]
    width, height = png_size(png)
    assert (width, height) == (1320, 825)  # 12 x 7.5 in at 110 dpi
    text = svg.read_text()
    for label in (
        "gripper force (N)",
        "joint angle (rad)",
        "side_grasp",
        "dropped",
        "grasp failed",
        "placed",
    ):
        assert label in text


def test_the_series_follow_the_recording(tmp_path: Path) -> None:
    series = SessionSeries.of(read_messages(session(tmp_path / "job.mcap")))
    assert [s for _, s in series.states] == ["idle", "detect", "plan", "side_grasp", "flip", "place"]
    assert len(series.force_t) == len(series.joints_t) == 300
    assert [(kind, mug) for _, kind, mug in series.events] == [
        ("grasp_failed", "m1"),
        ("mug_dropped", "m1"),
        ("mug_placed", "m1"),
    ]
    assert series.joint_names == ["a", "b"]
    assert series.end_s == pytest.approx(5.98)


def test_a_recording_cut_by_a_crash_is_drawn_up_to_the_cut(tmp_path: Path) -> None:
    data = session(tmp_path / "job.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    rec = read_messages(cut)
    assert rec.truncated
    series = SessionSeries.of(rec)
    assert 0 < series.end_s < 5.0
    png = tmp_path / "cut.png"
    assert main(["record", "plot", str(cut), "--png", str(png)]) == 0
    assert png_size(png) == (1320, 825)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "give --png OUT and/or --svg OUT"),
        (["--png", "{tmp}/x.jpg"], "--png {tmp}/x.jpg: the file name must end in .png"),
        (
            ["--svg", "{tmp}/nowhere/x.svg"],
            "--svg {tmp}/nowhere/x.svg: directory '{tmp}/nowhere' does not exist",
        ),
    ],
)
def test_plot_refuses_bad_requests_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    path = session(tmp_path / "job.mcap", seconds=0.5)
    capsys.readouterr()
    argv = ["record", "plot", str(path), *(a.format(tmp=tmp_path) for a in args)]
    assert main(argv) == 2
    assert capsys.readouterr().err == f"dishbot record: error: {message.format(tmp=tmp_path)}\n"


def test_plot_of_a_file_that_is_not_a_recording_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"hello")
    assert main(["record", "plot", str(bad), "--png", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == f"dishbot record: error: {bad}: not an MCAP file (bad magic)\n"
    assert not (tmp_path / "x.png").exists()


def test_without_matplotlib_the_plot_says_what_to_install(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    path = session(tmp_path / "job.mcap", seconds=0.5)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now raises ImportError
    capsys.readouterr()
    assert main(["record", "plot", str(path), "--png", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == (
        "dishbot record: error: plotting needs matplotlib: pip install 'dishbot[plot]'\n"
    )


def faulted_session(path: Path) -> Path:
    """A job whose detect and plan take no time (as in simulated time), a fault injected, a mug given up at
    the very last message and done entered with it."""
    with Recorder(path, chunk_size=2048) as rec:
        rec.write_header({"robot_id": "r1"}, {}, log_time_ns=T0, file={"kind": "job", "pid": 1})
        for i, state in enumerate(["idle", "detect", "plan", "side_grasp.approach"]):
            rec.write(
                "dishbot/r1/state",
                {"state": state, "mugs_total": 0, "mugs_placed": 0, "t": 0.0},
                log_time_ns=T0 + i,
            )
        for i in range(1, 200):
            rec.write(
                "dishbot/r1/joints",
                {"t": 0.0, "names": ["a"], "position_rad": [0.01 * i]},
                log_time_ns=T0 + i * 10**8,
            )
        rec.write(
            "dishbot/r1/events",
            {"kind": "fault_injected", "fault": "servo_overload", "servo": 3, "state": "flip.turn"},
            log_time_ns=T0 + 80 * 10**8,
        )
        rec.write(
            "dishbot/r1/state",
            {"state": "flip.turn", "mugs_total": 0, "mugs_placed": 0, "t": 0.0},
            log_time_ns=T0 + 50 * 10**8,
        )
        rec.write(
            "dishbot/r1/events", {"kind": "mug_given_up", "mug_id": "m12"}, log_time_ns=T0 + 200 * 10**8
        )
        rec.write(
            "dishbot/r1/state",
            {"state": "done", "mugs_total": 0, "mugs_placed": 0, "t": 0.0},
            log_time_ns=T0 + 200 * 10**8,
        )
    return path


def test_every_state_has_its_lane_and_is_drawn_visibly_however_short(tmp_path: Path) -> None:
    rec = read_messages(faulted_session(tmp_path / "job.mcap"))
    fig = session_figure(rec)
    try:
        fig.canvas.draw()
        ax_state = fig.axes[0]
        ticks = zip(ax_state.get_yticks(), ax_state.get_yticklabels(), strict=True)
        top_down = [label.get_text() for _, label in sorted(ticks, key=lambda tick: -tick[0])]
        assert top_down == ["events", "idle", "detect", "plan", "side_grasp", "flip", "done"]
        bars = [c for c in ax_state.collections if isinstance(c, PolyCollection)]
        assert len(bars) == 6  # one span per state entered
        pixels = [ax_state.transData.transform(c.get_paths()[0].vertices)[:, 0] for c in bars]
        assert min(float(x.max() - x.min()) for x in pixels) >= 3  # detect, plan and done too
    finally:
        plt.close(fig)


def test_an_injected_fault_is_marked_and_no_label_is_cut_at_the_edges(tmp_path: Path) -> None:
    rec = read_messages(faulted_session(tmp_path / "job.mcap"))
    fig = session_figure(rec)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        ax_state = fig.axes[0]
        labels = {a.get_text(): a for a in ax_state.texts}
        assert set(labels) == {"injected servo_overload", "m12"}
        legend = ax_state.get_legend()
        assert legend is not None
        assert [t.get_text() for t in legend.get_texts()] == ["given up", "injected fault"]
        dashed = [line for ax in fig.axes[:3] for line in ax.get_lines() if line.get_linestyle() == "--"]
        assert len(dashed) == 3  # through every panel, at the injection
        assert {line.get_xdata()[0] for line in dashed} == {8.0}  # type: ignore[index]
        box = ax_state.get_window_extent(renderer)
        for text in labels.values():  # the last label (m12, at the last message) too
            extent = text.get_window_extent(renderer)
            assert box.x0 <= extent.x0, text.get_text()
            assert extent.x1 <= box.x1, text.get_text()
        figure = fig.bbox
        texts = [fig.texts, *(ax.texts for ax in fig.axes)]
        texts += [[ax.xaxis.label, ax.yaxis.label] for ax in fig.axes]
        texts += [legend.get_texts() for ax in fig.axes if (legend := ax.get_legend()) is not None]
        for text in (t for group in texts for t in group if t.get_text()):
            extent = text.get_window_extent(renderer)
            assert figure.x0 <= extent.x0, text.get_text()
            assert extent.x1 <= figure.x1, text.get_text()
    finally:
        plt.close(fig)
