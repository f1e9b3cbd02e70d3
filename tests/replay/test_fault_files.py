"""Fault files: every kind of bad entry gets one line naming the entry and the field; valid files
round-trip."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.config import load_config
from daemon.errors import UsageError
from replay.faults import FAULT_KINDS, FaultSpec, dump_faults, load_fault_file, parse_faults
from statechart.chart import LEAVES

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "faults"


def error_of(text: str, *, config: bool = False) -> str:
    with pytest.raises(UsageError) as e:
        parse_faults(text, source="faults.toml", config=load_config() if config else None)
    message = str(e.value)
    assert "\n" not in message
    return message


def test_a_full_entry_parses_with_its_defaults() -> None:
    faults = parse_faults(
        '[[fault]]\nkind = "servo_overload"\nservo = 3\nat_state = "flip.turn"\nafter_s = 0.5\n\n'
        '[[fault]]\nkind = "fsr_spike"\nat_s = 12\n\n'
        '[[fault]]\nkind = "loop_stall"\nat_s = 1.5\n',
        source="faults.toml",
    )
    assert faults == (
        FaultSpec(index=1, kind="servo_overload", at_state="flip.turn", after_s=0.5, servo=3),
        FaultSpec(index=2, kind="fsr_spike", at_s=12.0, value_n=0.0),
        FaultSpec(index=3, kind="loop_stall", at_s=1.5, duration_s=2.0),
    )
    assert faults[0].to_json() == {
        "index": 1,
        "kind": "servo_overload",
        "at_state": "flip.turn",
        "occurrence": 1,
        "after_s": 0.5,
        "servo": 3,
    }
    assert faults[1].to_json() == {"index": 2, "kind": "fsr_spike", "at_s": 12.0, "value_n": 0.0}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            '[[fault]]\nkind = "servo_overload"\nat_s = 1\n',
            "faults.toml: fault 1 (servo_overload): servo: missing (the servo ID the fault acts on)",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1\n\n[[fault]]\nkind = "servo_overload"\nat_s = 2\n',
            "faults.toml: fault 2 (servo_overload): servo: missing (the servo ID the fault acts on)",
        ),
        ("[[fault]]\nat_s = 1\n", "faults.toml: fault 1: kind: missing (one of servo_overload, "),
        (
            '[[fault]]\nkind = "gremlins"\nat_s = 1\n',
            "faults.toml: fault 1: kind: 'gremlins' is not one of servo_overload, ",
        ),
        ("[[fault]]\nkind = 3\nat_s = 1\n", "faults.toml: fault 1: kind: 3 is not one of servo_overload, "),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1\ncolour = "red"\n',
            "faults.toml: fault 1 (fsr_drop): colour: unknown key (allowed: kind, at_s, at_state, "
            "occurrence, after_s, duration_s)",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\n',
            "faults.toml: fault 1 (fsr_drop): at_s: missing: give at_s (simulated seconds from the session "
            "start) or at_state",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1\nat_state = "detect"\n',
            "faults.toml: fault 1 (fsr_drop): at_state: give either at_s or at_state, not both",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = -1\n',
            "faults.toml: fault 1 (fsr_drop): at_s: -1 is out of range; allowed [0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = "soon"\n',
            "faults.toml: fault 1 (fsr_drop): at_s: expected a number in [0, 86400] s, got 'soon'",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = true\n',
            "faults.toml: fault 1 (fsr_drop): at_s: expected a number in [0, 86400] s, got true",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = nan\n',
            "faults.toml: fault 1 (fsr_drop): at_s: nan is out of range; allowed [0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1\nduration_s = 0\n',
            "faults.toml: fault 1 (fsr_drop): duration_s: 0 is out of range; allowed (0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_state = "flip.spin"\n',
            "faults.toml: fault 1 (fsr_drop): at_state: 'flip.spin' is not a state of the chart (e.g. "
            "detect, flip, flip.turn, place.release)",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_state = "flip.turn"\noccurrence = 0\n',
            "faults.toml: fault 1 (fsr_drop): occurrence: 0 is out of range; allowed [1, 10000]",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_state = "flip.turn"\noccurrence = 1.5\n',
            "faults.toml: fault 1 (fsr_drop): occurrence: expected an integer in [1, 10000], got 1.5",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_state = "flip.turn"\nafter_s = -0.5\n',
            "faults.toml: fault 1 (fsr_drop): after_s: -0.5 is out of range; allowed [0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 2\nafter_s = 1\n',
            "faults.toml: fault 1 (fsr_drop): after_s: only with at_state (at_s already says when)",
        ),
        (
            '[[fault]]\nkind = "mug_slip"\nat_s = 2\nduration_s = 1\n',
            "faults.toml: fault 1 (mug_slip): duration_s: mug_slip happens once; it takes no duration",
        ),
        (
            '[[fault]]\nkind = "bus_corrupt"\nat_s = 2\n',
            "faults.toml: fault 1 (bus_corrupt): rate: missing (the fraction of status packets corrupted, in "
            "(0, 1])",
        ),
        (
            '[[fault]]\nkind = "bus_corrupt"\nat_s = 2\nrate = 1.5\n',
            "faults.toml: fault 1 (bus_corrupt): rate: 1.5 is out of range; allowed (0, 1]",
        ),
        (
            '[[fault]]\nkind = "bus_corrupt"\nat_s = 2\nrate = 0\n',
            "faults.toml: fault 1 (bus_corrupt): rate: 0 is out of range; allowed (0, 1]",
        ),
        (
            '[[fault]]\nkind = "servo_silent"\nat_s = 2\nservo = "3"\n',
            "faults.toml: fault 1 (servo_silent): servo: expected an integer in [0, 253], got '3'",
        ),
        (
            '[[fault]]\nkind = "servo_silent"\nat_s = 2\nservo = 300\n',
            "faults.toml: fault 1 (servo_silent): servo: 300 is out of range; allowed [0, 253]",
        ),
        (
            '[[fault]]\nkind = "bus_unplug"\nat_s = 2\ndevice = "camera"\n',
            "faults.toml: fault 1 (bus_unplug): device: 'camera' is not one of servo, fsr",
        ),
        (
            '[[fault]]\nkind = "fsr_spike"\nat_s = 2\nvalue_n = -3\n',
            "faults.toml: fault 1 (fsr_spike): value_n: -3 is out of range; allowed [0, 1000] N",
        ),
        (
            '[[fault]]\nkind = "mug_moved"\nat_s = 2\n',
            "faults.toml: fault 1 (mug_moved): dx_m: missing: say how far to move the mug (dx_m, dy_m in "
            "metres, not both 0)",
        ),
        (
            '[[fault]]\nkind = "mug_moved"\nat_s = 2\ndx_m = "far"\n',
            "faults.toml: fault 1 (mug_moved): dx_m: expected a number in [-1, 1] m, got 'far'",
        ),
        (
            '[[fault]]\nkind = "mug_moved"\nat_s = 2\ndx_m = 0.05\nmug = ""\n',
            "faults.toml: fault 1 (mug_moved): mug: expected a non-empty string, got ''",
        ),
        ("", "faults.toml: no [[fault]] table; list the faults as [[fault]] tables"),
        ('fault = "servo_overload"\n', "faults.toml: fault: must be a list of [[fault]] tables"),
        (
            '[faults]\nkind = "x"\n',
            "faults.toml: faults: unknown key (a fault file holds only [[fault]] tables)",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = \n',
            "faults.toml: line 3: not valid TOML: Invalid value",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1\nat_s = 2\n',
            "faults.toml: line 4: not valid TOML: Cannot overwrite a value",
        ),
    ],
)
def test_a_bad_entry_is_one_line_naming_the_entry_and_the_field(text: str, message: str) -> None:
    assert error_of(text).startswith(message)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            '[[fault]]\nkind = "loop_stall"\nat_s = 1\nduration_s = 1e300\n',
            "faults.toml: fault 1 (loop_stall): duration_s: 1e+300 is out of range; allowed (0, 60] s",
        ),
        (
            '[[fault]]\nkind = "loop_stall"\nat_s = 1\nduration_s = 1e6\n',
            "faults.toml: fault 1 (loop_stall): duration_s: 1000000 is out of range; allowed (0, 60] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1\nduration_s = 1e300\n',
            "faults.toml: fault 1 (fsr_drop): duration_s: 1e+300 is out of range; allowed (0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_s = 1e9\n',
            "faults.toml: fault 1 (fsr_drop): at_s: 1000000000 is out of range; allowed [0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_state = "detect"\nafter_s = 1e7\n',
            "faults.toml: fault 1 (fsr_drop): after_s: 10000000 is out of range; allowed [0, 86400] s",
        ),
        (
            '[[fault]]\nkind = "fsr_drop"\nat_state = "detect"\noccurrence = 1000000\n',
            "faults.toml: fault 1 (fsr_drop): occurrence: 1000000 is out of range; allowed [1, 10000]",
        ),
        (
            '[[fault]]\nkind = "mug_moved"\nat_s = 1\ndx_m = 1e6\n',
            "faults.toml: fault 1 (mug_moved): dx_m: 1000000 is out of range; allowed [-1, 1] m",
        ),
        (
            '[[fault]]\nkind = "mug_moved"\nat_s = 1\ndy_m = -3\n',
            "faults.toml: fault 1 (mug_moved): dy_m: -3 is out of range; allowed [-1, 1] m",
        ),
        (
            '[[fault]]\nkind = "bus_corrupt"\nat_s = 1\nrate = 0.1\nseed = 1099511627776\n',
            "faults.toml: fault 1 (bus_corrupt): seed: 1099511627776 is out of range; allowed "
            "[0, 4294967295]",
        ),
        (
            '[[fault]]\nkind = "fsr_spike"\nat_s = 1\nvalue_n = 1e5\n',
            "faults.toml: fault 1 (fsr_spike): value_n: 100000 is out of range; allowed [0, 1000] N",
        ),
        (
            '[[fault]]\nkind = "mug_moved"\nat_s = 1\ndx_m = 0.1\nmug = "' + "m" * 65 + '"\n',
            "faults.toml: fault 1 (mug_moved): mug: expected at most 64 characters, got 65",
        ),
    ],
)
def test_every_number_has_a_range_and_a_value_outside_it_is_one_line(text: str, message: str) -> None:
    assert error_of(text).startswith(message)


def test_a_servo_outside_the_configured_chain_is_refused_with_the_config() -> None:
    text = '[[fault]]\nkind = "servo_overheat"\nat_s = 1\nservo = 9\n'
    assert parse_faults(text, source="faults.toml")[0].servo == 9  # without a config: any ID
    assert error_of(text, config=True) == (
        "faults.toml: fault 1 (servo_overheat): servo: no servo 9 in the configured chain (1, 2, 3, 4, 5, 6)"
    )


def test_a_missing_or_unreadable_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match=r"^.*nope\.toml: no such fault file$"):
        load_fault_file(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe[[fault]]")
    with pytest.raises(UsageError, match=r"bad\.toml: cannot read the fault file: "):
        load_fault_file(bad)


def test_the_example_fault_files_parse() -> None:
    files = sorted(EXAMPLES.glob("*.toml"))
    assert len(files) >= 2
    for path in files:
        assert load_fault_file(path, config=load_config())


_times = st.floats(min_value=0.0, max_value=1e4, allow_nan=False, allow_infinity=False)
_positive = st.floats(min_value=1e-3, max_value=1e3, allow_nan=False, allow_infinity=False)
_stalls = st.floats(min_value=1e-3, max_value=60.0, allow_nan=False, allow_infinity=False)
_offsets = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_infinity=False).filter(bool)


@st.composite
def fault_specs(draw: st.DrawFn, index: int) -> FaultSpec:
    kind = draw(st.sampled_from(sorted(FAULT_KINDS)))
    spec = FAULT_KINDS[kind]
    values: dict[str, object] = {}
    if draw(st.booleans()):
        values["at_s"] = draw(_times)
    else:
        values["at_state"] = draw(st.sampled_from(LEAVES))
        values["occurrence"] = draw(st.integers(min_value=1, max_value=5))
        values["after_s"] = draw(_times)
    if "duration_s" in spec.keys and draw(st.booleans()):
        values["duration_s"] = draw(_stalls if kind == "loop_stall" else _positive)
    elif kind == "loop_stall":
        values["duration_s"] = 2.0
    if "servo" in spec.keys and (kind != "bus_corrupt" or draw(st.booleans())):
        values["servo"] = draw(st.integers(min_value=1, max_value=6))
    if kind == "bus_corrupt":
        values["rate"] = draw(st.floats(min_value=1e-6, max_value=1.0))
        values["seed"] = draw(st.integers(min_value=0, max_value=2**31))
    if kind == "bus_unplug":
        values["device"] = draw(st.sampled_from(("servo", "fsr")))
    if kind == "fsr_spike":
        values["value_n"] = draw(st.floats(min_value=0.0, max_value=100.0))
    if kind == "mug_moved":
        values["dx_m"], values["dy_m"] = draw(_offsets), draw(_offsets)
        if draw(st.booleans()):
            values["mug"] = draw(st.text(alphabet='abcm0123456789_-"\\ é', min_size=1, max_size=8))
    return FaultSpec(index=index, kind=kind, **values)  # type: ignore[arg-type]


@st.composite
def fault_files(draw: st.DrawFn) -> tuple[FaultSpec, ...]:
    count = draw(st.integers(min_value=1, max_value=6))
    return tuple(draw(fault_specs(i)) for i in range(1, count + 1))


@settings(max_examples=150, deadline=None)
@given(fault_files())
@pytest.mark.slow
def test_a_valid_fault_file_round_trips(faults: tuple[FaultSpec, ...]) -> None:
    assert parse_faults(dump_faults(faults), source="faults.toml", config=load_config()) == faults


def test_the_docs_list_every_kind_and_their_example_parses() -> None:
    doc = (Path(__file__).resolve().parents[2] / "docs" / "recording.md").read_text()
    section = doc.split("### Fault files", 1)[1]
    listed = re.findall(r"^\| `([a-z_]+)` \|", section, flags=re.MULTILINE)
    assert listed == list(FAULT_KINDS)
    example = re.findall(r"```toml\n(.*?)```", section, flags=re.DOTALL)[0]
    faults = parse_faults(example, source="recording.md", config=load_config())
    assert [(f.kind, f.at_state, f.occurrence) for f in faults] == [
        ("servo_overload", "flip.turn", 1),
        ("mug_slip", "flip", 2),
    ]
    shown = re.findall(r"^dishbot run: error: (faults\.toml: fault 2 .*)$", section, flags=re.MULTILINE)
    text = '[[fault]]\nkind = "fsr_drop"\nat_s = 1\n\n[[fault]]\nkind = "servo_overload"\nat_s = 2\n'
    assert shown == [error_of(text)]
    ranged = re.findall(r"^dishbot replay: error: (faults\.toml: .*)$", section, flags=re.MULTILINE)
    assert ranged == [error_of('[[fault]]\nkind = "loop_stall"\nat_s = 1\nduration_s = 1e300\n')]
