"""The one validator: each class of bad input gets one line naming the field, in the one wording."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Annotated, Any, ClassVar, Literal

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from validation import FINITE, NON_EMPTY, UNKNOWN_KEYS_IGNORED, Invalid, OneOf, above, convert, within


@dataclass(frozen=True, slots=True)
class Inner:
    rate: Annotated[float, above(0.0, 60.0)]
    pair: tuple[Annotated[int, within(0, 9)], Annotated[int, within(0, 9)]] = (0, 0)

    def __post_init__(self) -> None:
        if self.pair[0] > self.pair[1]:
            raise Invalid(f"pair: {self.pair[0]} must not be above {self.pair[1]}")


@dataclass(frozen=True, slots=True)
class Outer:
    method: Annotated[str, OneOf(("auto", "exact"))]
    fitness: Literal["rf", "ws"]
    limit_s: Annotated[float, within(0.01, 600.0)]
    seed: Annotated[int, within(0, 2**31 - 1)]
    flag: bool
    name: Annotated[str, NON_EMPTY]
    inner: Inner
    items: Annotated[list[Inner], msgspec.Meta(min_length=1, max_length=3)]
    optional: Annotated[str, OneOf(("a", "b"))] | None = None
    code: Annotated[
        str, msgspec.Meta(pattern=r"^[a-z]{2}$", extra={"expected": "two lower-case letters"})
    ] = "ab"


GOOD: dict[str, Any] = {
    "method": "auto",
    "fitness": "rf",
    "limit_s": 1,
    "seed": 3,
    "flag": True,
    "name": "x",
    "inner": {"rate": 1.5},
    "items": [{"rate": 2, "pair": [1, 2]}],
}


def test_a_good_value_is_built_as_the_declared_type() -> None:
    out = convert(GOOD, Outer)
    assert out == Outer("auto", "rf", 1.0, 3, True, "x", Inner(1.5), [Inner(2.0, (1, 2))])
    assert isinstance(out.limit_s, float)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"limit_s": 900}, "cfg.limit_s: 900 is out of range; allowed [0.01, 600]"),
        ({"limit_s": math.nan}, "cfg.limit_s: nan is out of range; allowed [0.01, 600]"),
        ({"limit_s": 10**400}, "cfg.limit_s: an integer of 401 digits is out of range; allowed [0.01, 600]"),
        ({"limit_s": "1"}, "cfg.limit_s: expected a number in [0.01, 600], got '1'"),
        ({"seed": True}, "cfg.seed: expected an integer in [0, 2147483647], got true"),
        ({"seed": 1.5}, "cfg.seed: expected an integer in [0, 2147483647], got 1.5"),
        ({"method": "fast"}, "cfg.method: 'fast' is not one of auto, exact"),
        ({"optional": "c"}, "cfg.optional: 'c' is not one of a, b"),
        ({"fitness": "fast"}, "cfg.fitness: 'fast' is not one of rf, ws"),
        ({"flag": 1}, "cfg.flag: expected true or false, got 1"),
        ({"name": ""}, "cfg.name: expected a non-empty string, got ''"),
        ({"inner": 3}, "cfg.inner: expected a table, got 3"),
        ({"inner": {"rate": 0}}, "cfg.inner.rate: 0 is out of range; allowed (0, 60]"),
        ({"inner": {}}, "cfg.inner.rate: missing"),
        (
            {"inner": {"rate": 1, "colour": 2}},
            "cfg.inner.colour: unknown key in cfg.inner (known keys: pair, rate)",
        ),
        ({"items": []}, "cfg.items: expected 1-3 values, got 0"),
        ({"items": "x"}, "cfg.items: expected a list, got 'x'"),
        ({"items": [{"rate": 1, "pair": [1]}]}, "cfg.items[0].pair: expected 2 values, got 1"),
        (
            {"items": [{"rate": 1, "pair": [1, 10]}]},
            "cfg.items[0].pair[1]: 10 is out of range; allowed [0, 9]",
        ),
        ({"items": [{"rate": 1, "pair": [2, 1]}]}, "cfg.items[0].pair: 2 must not be above 1"),
        ({"code": "ABC"}, "cfg.code: expected two lower-case letters, got 'ABC'"),
    ],
)
def test_each_class_of_bad_value_is_one_line_naming_the_field(change: dict[str, Any], message: str) -> None:
    with pytest.raises(Invalid) as info:
        convert({**GOOD, **change}, Outer, name="cfg")
    assert str(info.value) == message


def test_a_missing_key_and_an_unknown_one_at_the_top_say_where_they_are() -> None:
    data = {k: v for k, v in GOOD.items() if k != "seed"}
    with pytest.raises(Invalid, match=r"^seed: missing; add it$"):
        convert(data, Outer, missing="missing; add it")
    with pytest.raises(Invalid, match=r"^speed: unknown key in start \(known keys: code, fitness,"):
        convert({**GOOD, "speed": 1}, Outer, root="start")
    with pytest.raises(Invalid, match=r"^profile p\.toml: speed: unknown key"):
        convert({**GOOD, "speed": 1}, Outer, prefix="profile p.toml: ")


def test_the_error_type_is_the_callers() -> None:
    class Refused(ValueError):
        pass

    with pytest.raises(Refused, match=r"^limit_s: 0 is out of range"):
        convert({**GOOD, "limit_s": 0}, Outer, error=Refused)


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None)
@given(data=_json, base=st.booleans())
def test_any_json_is_built_or_refused_in_one_line_never_another_error(data: object, base: bool) -> None:
    value = {**GOOD, **data} if base and isinstance(data, dict) else data
    try:
        convert(value, Outer, name="cfg")
    except Invalid as e:
        text = str(e)
        assert "\n" not in text
        assert text.startswith("cfg")
        assert len(text) < 300


def test_a_trailing_newline_is_not_part_of_a_valid_name() -> None:
    """``$`` matches before a final newline: names, ids and endpoints are checked to their very end."""
    from daemon.commands_handler import BadCommand, parse
    from daemon.config import load_config
    from daemon.errors import ConfigError
    from daemon.security import check_endpoint, check_name

    with pytest.raises(ConfigError, match=r"^robot_id: 'r1\\n' is not allowed"):
        load_config(overrides={"robot_id": "r1\n"})
    with pytest.raises(ConfigError, match=r"is not a Zenoh endpoint"):
        check_endpoint("tcp/127.0.0.1:3474\n", "zenoh.listen[0]")
    with pytest.raises(ConfigError, match=r"is not a valid name"):
        check_name("bob\n", "zenoh.access.operators[0]")
    body = b'{"mugs": [{"id": "m1\\n", "type": "big", "x_m": 0.1, "y_m": 0.4}]}'
    with pytest.raises(BadCommand, match=r"^mugs\[0\]\.id: expected 1-32 letters"):
        parse("start", body, load_config())


@dataclass(frozen=True, slots=True)
class Lenient:
    unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED
    x: Annotated[float, FINITE]


@dataclass(frozen=True, slots=True)
class Strict:
    lenient: Lenient
    items: tuple[Lenient, ...] = ()


def test_a_shape_may_pass_over_keys_it_does_not_declare_where_its_format_always_has() -> None:
    assert convert({"lenient": {"x": 1, "colour": "red"}, "items": [{"x": 2, "y": 3}]}, Strict) == Strict(
        Lenient(1.0), (Lenient(2.0),)
    )
    with pytest.raises(Invalid, match=r"^colour: unknown key in the problem \(known keys: items, lenient\)$"):
        convert({"lenient": {"x": 1}, "colour": "red"}, Strict, root="the problem")


@pytest.mark.parametrize(
    ("x", "message"),
    [
        (math.inf, "lenient.x: expected a finite number, got inf"),
        (-math.inf, "lenient.x: expected a finite number, got -inf"),
        (math.nan, "lenient.x: expected a finite number, got nan"),
        ("north", "lenient.x: expected a finite number, got 'north'"),
        (None, "lenient.x: expected a finite number, got None"),
    ],
)
def test_a_finite_number_refuses_infinity_nan_and_other_types(x: object, message: str) -> None:
    with pytest.raises(Invalid) as info:
        convert({"lenient": {"x": x}}, Strict)
    assert str(info.value) == message
    assert convert({"lenient": {"x": -1e300}}, Strict).lenient.x == -1e300


def test_a_wrong_value_at_the_top_is_named_by_the_root() -> None:
    with pytest.raises(Invalid, match=r"^the problem: expected a table, got a list$"):
        convert([1, 2], Strict, root="the problem")
    with pytest.raises(Invalid, match=r"^the top level: expected a table, got 3$"):
        convert(3, Strict)


def test_the_public_names_are_the_modules_own() -> None:
    import validation

    assert all(hasattr(validation, name) for name in validation.__all__)


class Colour(StrEnum):
    RED = "red"
    GREEN = "green"


@dataclass(frozen=True, slots=True)
class Paint:
    colour: Colour


def test_an_enum_field_names_its_values_and_is_built_as_the_enum() -> None:
    assert convert({"colour": "green"}, Paint).colour is Colour.GREEN
    with pytest.raises(Invalid) as e:
        convert({"colour": "blue"}, Paint, name="paint")
    assert str(e.value) == "paint.colour: 'blue' is not one of red, green"
