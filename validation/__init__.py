"""One validator for everything dishbot reads from people and files, with one wording.

The shape of a config section, a fault file's entry, a command body or a problem file is declared once, as a
dataclass whose fields carry their ranges and choices (``Annotated[float, within(0.01, 600)]``,
``Annotated[str, OneOf(METHODS)]``); ``convert`` checks a decoded TOML or JSON value against it and builds it.
The checking is msgspec's (``msgspec.convert``, strict: no string is taken for a number, no ``true`` for 1);
this module adds what msgspec leaves to its callers: unknown keys refused (msgspec ignores them on
dataclasses; a shape whose format has always let them through says so with ``UNKNOWN_KEYS_IGNORED``),
choices from lists known only at run time, and one error wording, naming the field by its dotted path in
the file::

    planner.time_limit_s: 900 is out of range; allowed [0.01, 600]
    planner.method: 'fastest' is not one of auto, ffd, ...
    hardware.fsr.gain: expected a number in [0.001, 1000], got 'high'
    sim.speedd: unknown key in sim (known keys: detection_noise_m, ...)

Cross-field rules (a release threshold below its press threshold) stay with the types they belong to, and
raise through ``Invalid`` with the same ``name: what is wrong`` form.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import sys
import types
from collections.abc import Hashable, Mapping, Sequence
from typing import Any, Final, TypeVar, cast

import msgspec

T = TypeVar("T")


class Invalid(ValueError):
    """A value that does not meet its declaration; the message is one line naming the field."""


def within(lo: float, hi: float, *, unit: str = "") -> msgspec.Meta:
    """The closed range ``[lo, hi]`` of a number, in ``unit`` (said after the range in messages)."""
    return msgspec.Meta(ge=lo, le=hi, extra={"unit": unit} if unit else None)


def above(lo: float, hi: float, *, unit: str = "") -> msgspec.Meta:
    """The half-open range ``(lo, hi]`` of a number: ``lo`` itself is not allowed."""
    return msgspec.Meta(gt=lo, le=hi, extra={"unit": unit} if unit else None)


# A string with at least one character.
NON_EMPTY: Final = msgspec.Meta(min_length=1)

# Any number but infinity and NaN, for a quantity with no natural bound (a position, an angle).
FINITE: Final = msgspec.Meta(
    ge=-sys.float_info.max, le=sys.float_info.max, extra={"expected": "a finite number"}
)

# ``unknown_keys: ClassVar[str] = UNKNOWN_KEYS_IGNORED`` on a shape lets keys it does not declare through
# unread, where the format always has (a recording's message, which later versions extend; the tables
# inside a placement problem); every other shape refuses them.
UNKNOWN_KEYS_IGNORED: Final = "ignored"


@dataclasses.dataclass(frozen=True, slots=True)
class OneOf:
    """The values a string field may take, when they are known only at run time (``Literal`` otherwise)."""

    values: tuple[str, ...]


def convert(
    data: object,
    kind: type[T],
    *,
    name: str = "",
    error: type[Exception] = Invalid,
    missing: str = "missing",
    root: str = "the top level",
    prefix: str = "",
) -> T:
    """``data`` (decoded TOML or JSON) checked against ``kind`` and built as one; ``error`` (one line, the
    field named ``name`` + its path) otherwise. ``missing`` is what a missing key's message says, ``root``
    what an unknown key at the top is said to be in; ``prefix`` goes before every message (the file, when
    the names are the file's own)."""
    info = _info(cast(Hashable, kind))
    problem = _check_keys(data, info, name, missing, root) or _check_choices(data, kind, name)
    if problem is not None:
        raise error(prefix + problem)
    try:
        return msgspec.convert(data, kind, strict=True)
    except msgspec.ValidationError as e:
        raise error(prefix + _worded(str(e), data, info, name, missing, root)) from None


@functools.cache
def _info(kind: Hashable) -> Any:
    """msgspec's description of a declared type (built once per type: it walks every field)."""
    return msgspec.inspect.type_info(kind)


def show(value: object) -> str:
    """A value as an error message shows it."""
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list | tuple):
        return "a list"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int) and abs(value) > 10**15:
        return f"an integer of {len(str(abs(value)))} digits"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))  # 1e9 as a file holds it, not 1000000000.0
    return repr(value)


def number_range(lo: float | None, hi: float | None, *, open_low: bool = False) -> str:
    """``[lo, hi]`` (``(lo, hi]`` when ``lo`` itself is not allowed) as the messages write it."""
    left = "(" if open_low else "["
    low = "-inf" if lo is None else _bound(lo)
    high = "inf" if hi is None else _bound(hi)
    return f"{left}{low}, {high}]"


def _bound(value: float) -> str:
    """``4294967295``, ``0.01``, ``6.28319``: whole numbers in full, others short."""
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return f"{value:g}"


_PLAIN_KEY: Final = re.compile(r"^[A-Za-z0-9_.-]{1,64}\Z")


def key_name(name: str, key: str | int) -> str:
    """``name`` and one key below it as an error names them: ``a.b``, ``a[3]``, or quoted on one line when
    the key is no plain word (``mug_types['\\n']``)."""
    return _join(name, key)


def _join(name: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{name}[{key}]"
    if not _PLAIN_KEY.match(key):  # a key as a file can spell it: quoted, on one line
        return f"{name}[{key[:64]!r}]"
    return f"{name}.{key}" if name else key


# --- what msgspec leaves to its callers -------------------------------------------------------------------


def _fields(info: Any) -> dict[str, Any] | None:
    info = _unwrapped(info)
    if isinstance(info, msgspec.inspect.DataclassType | msgspec.inspect.StructType):
        return {f.name: f for f in info.fields}
    return None


def _check_keys(data: object, info: Any, name: str, missing: str, root: str = "") -> str | None:
    """Unknown keys and missing ones, depth first, in the order the file has them."""
    info = _unwrapped(info)
    fields = _fields(info)
    if fields is not None:
        if not isinstance(data, Mapping):
            return None  # msgspec words it ("expected a table")
        ignored = getattr(info.cls, "unknown_keys", None) == UNKNOWN_KEYS_IGNORED
        for key in data:
            if key not in fields and not ignored:
                where = name or root
                known = ", ".join(sorted(fields))
                return f"{_join(name, str(key))}: unknown key in {where} (known keys: {known})"
        for field_name, f in fields.items():
            if field_name not in data:
                if f.required:
                    return f"{_join(name, field_name)}: {missing}"
                continue
            found = _check_keys(data[field_name], f.type, _join(name, field_name), missing)
            if found is not None:
                return found
        return None
    if isinstance(info, msgspec.inspect.DictType) and isinstance(data, Mapping):
        for key, value in data.items():
            found = _check_keys(value, info.value_type, _join(name, str(key)), missing)
            if found is not None:
                return found
    elif isinstance(info, msgspec.inspect.ListType | msgspec.inspect.VarTupleType) and _is_list(data):
        for i, value in enumerate(data):  # type: ignore[arg-type]
            found = _check_keys(value, info.item_type, _join(name, i), missing)
            if found is not None:
                return found
    elif isinstance(info, msgspec.inspect.TupleType) and _is_list(data):
        for i, (value, item) in enumerate(zip(data, info.item_types, strict=False)):  # type: ignore[call-overload]
            found = _check_keys(value, item, _join(name, i), missing)
            if found is not None:
                return found
    elif isinstance(info, msgspec.inspect.UnionType):
        for member in info.types:
            if _fields(member) is not None and isinstance(data, Mapping):
                return _check_keys(data, member, name, missing)
    return None


def _is_list(data: object) -> bool:
    return isinstance(data, list | tuple)


def _check_choices(data: object, kind: Any, name: str) -> str | None:
    """``OneOf`` fields: the value is one of the listed ones (other types are msgspec's to word)."""
    if not isinstance(kind, type) or not dataclasses.is_dataclass(kind) or not isinstance(data, Mapping):
        return None
    hints = _annotations(kind)
    for f in dataclasses.fields(kind):
        if f.name not in data:
            continue
        value = data[f.name]
        hint = hints.get(f.name)
        choices = _one_of(hint)
        if choices is not None and isinstance(value, str) and value not in choices.values:
            return f"{_join(name, f.name)}: {value!r} is not one of {', '.join(choices.values)}"
        inner = _dataclass_in(hint)
        if inner is not None:
            found = _check_choices(value, inner, _join(name, f.name))
            if found is not None:
                return found
    return None


_HINTS: dict[type, dict[str, Any]] = {}


def _annotations(kind: type) -> dict[str, Any]:
    if kind not in _HINTS:
        import typing

        _HINTS[kind] = typing.get_type_hints(kind, include_extras=True)
    return _HINTS[kind]


def _one_of(hint: Any) -> OneOf | None:
    import typing

    if typing.get_origin(hint) in (typing.Union, types.UnionType):  # an optional field
        members = [a for a in typing.get_args(hint) if a is not type(None)]
        hint = members[0] if len(members) == 1 else hint
    for meta in getattr(hint, "__metadata__", ()):
        if isinstance(meta, OneOf):
            return meta
    return None


def _dataclass_in(hint: Any) -> type | None:
    import typing

    if typing.get_origin(hint) in (typing.Union, types.UnionType):  # an optional table
        members = [a for a in typing.get_args(hint) if a is not type(None)]
        hint = members[0] if len(members) == 1 else hint
    if typing.get_origin(hint) is typing.Annotated:
        hint = typing.get_args(hint)[0]
    return hint if isinstance(hint, type) and dataclasses.is_dataclass(hint) else None


# --- msgspec's messages in dishbot's words ----------------------------------------------------------------

_AT: Final = re.compile(r"^(?P<what>.*?)(?: - at `\$(?P<path>[^`]*)`)?$", re.S)
_PATH_TOKEN: Final = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]|\[\.\.\.\]")
_BOUND: Final = re.compile(r"^Expected `(?P<type>\w+)` (?P<op>>=|<=|>|<) ")
_TYPE: Final = re.compile(r"^Expected `(?P<want>[^`]+)`, got `(?P<got>\w+)`")
_LENGTH: Final = re.compile(r"^Expected `array` of length (?P<n>\d+), got (?P<got>\d+)")
_ARRAY_LENGTH: Final = re.compile(r"^Expected `array` of length (?:>=|<=) \d+")
_TOO_BIG: Final = re.compile(r"^Number out of range")
_STR_LENGTH: Final = re.compile(r"^Expected `str` of length >= 1")
_STR_TOO_LONG: Final = re.compile(r"^Expected `str` of length <= \d+")
_MISSING: Final = re.compile(r"^Object missing required field `(?P<field>[^`]+)`")
_ENUM: Final = re.compile(r"^Invalid enum value (?P<value>.+)\Z")
_OWN_RULE: Final = re.compile(
    r"^(?P<field>[A-Za-z_][A-Za-z0-9_]*)(?P<index>(?:\[\d+\])*): (?P<text>.*)$", re.S
)


def _worded(message: str, data: object, info: Any, name: str, missing: str, root: str) -> str:
    match = _AT.match(message)
    assert match is not None
    what, path = match["what"], match["path"] or ""
    keys: list[str | int] = []
    for token in _PATH_TOKEN.finditer(path):
        if token[1] is not None:
            keys.append(token[1])
        elif token[2] is not None:
            keys.append(int(token[2]))
        else:
            keys.append("...")
    where = name
    for key in keys:
        where = _join(where, key)
    value = _value_at(data, keys)
    extra = _extra(info, keys)
    expected = extra.get("expected")
    unit = f" {extra['unit']}" if extra.get("unit") else ""
    field = _type_at(info, keys)
    shown = where or root  # the value itself is wrong: the whole file, command or table
    if (m := _MISSING.match(what)) is not None:
        return f"{_join(where, m['field'])}: {missing}"
    if expected is not None:  # the declaration words what it takes itself
        return f"{shown}: expected {expected}, got {show(value)}"
    if (_BOUND.match(what) or _TOO_BIG.match(what)) and isinstance(value, int | float):
        lo, hi, open_low = _bounds(field)
        what_is = "nan" if isinstance(value, float) and math.isnan(value) else show(value)
        return f"{shown}: {what_is} is out of range; allowed {number_range(lo, hi, open_low=open_low)}{unit}"
    if (m := _LENGTH.match(what)) is not None:
        return f"{shown}: expected {m['n']} values, got {m['got']}"
    if _ARRAY_LENGTH.match(what) is not None and _is_list(value):
        low, high = getattr(field, "min_length", None), getattr(field, "max_length", None)
        wanted = f"{low or 0}-{high}" if high is not None else f"at least {low}"
        return f"{shown}: expected {wanted} values, got {len(value)}"  # type: ignore[arg-type]
    if _STR_LENGTH.match(what) is not None:
        return f"{shown}: expected a non-empty string, got {show(value)}"
    if _STR_TOO_LONG.match(what) is not None and isinstance(value, str):
        return f"{shown}: expected at most {field.max_length} characters, got {len(value)}"
    if (m := _ENUM.match(what)) is not None:
        values = field.values if hasattr(field, "values") else [m.value for m in getattr(field, "cls", ())]
        return f"{shown}: {show(value)} is not one of {', '.join(str(v) for v in values)}"
    if _TYPE.match(what) is not None:
        return f"{shown}: expected {_expected(field)}{unit}, got {show(value)}"
    own = _OWN_RULE.match(what)
    fields = _fields(field)
    if own is not None and fields is not None and own["field"] in fields:
        return f"{_join(where, own['field'])}{own['index']}: {own['text']}"  # a type's rule, naming its field
    return f"{shown}: {what}"


def _value_at(data: object, keys: Sequence[str | int]) -> object:
    for key in keys:
        if isinstance(key, int) and _is_list(data) and 0 <= key < len(data):  # type: ignore[arg-type]
            data = data[key]  # type: ignore[index]
        elif isinstance(key, str) and isinstance(data, Mapping) and key in data:
            data = data[key]
        else:
            return None
    return data


def _extra(info: Any, keys: Sequence[str | int]) -> Mapping[str, Any]:
    """The ``extra`` of the declaration at ``keys`` (``msgspec.Meta(extra={"expected": ...})``)."""
    return _peeled(_type_at(info, keys, unwrap=False))[1]


def _type_at(info: Any, keys: Sequence[str | int], *, unwrap: bool = True) -> Any:
    for key in keys:
        info = _unwrapped(info)
        fields = _fields(info)
        if fields is not None and isinstance(key, str) and key in fields:
            info = fields[key].type
        elif isinstance(info, msgspec.inspect.TupleType) and isinstance(key, int):
            info = info.item_types[key] if key < len(info.item_types) else None
        elif isinstance(info, msgspec.inspect.ListType | msgspec.inspect.VarTupleType):
            info = info.item_type
        elif isinstance(info, msgspec.inspect.DictType):
            info = info.value_type
        else:
            return None
    return _unwrapped(info) if unwrap else info


def _unwrapped(info: Any) -> Any:
    """An optional value's own type (``float | None`` is a float where it is given), without its
    annotations (``_extra`` reads those)."""
    return _peeled(info)[0]


def _peeled(info: Any) -> tuple[Any, dict[str, Any]]:
    """``info`` without optional-ness and annotations, and the annotations' ``extra``."""
    extra: dict[str, Any] = {}
    while True:
        if isinstance(info, msgspec.inspect.Metadata):
            extra.update(info.extra or {})
            info = info.type
            continue
        if isinstance(info, msgspec.inspect.UnionType):
            members = [t for t in info.types if not isinstance(t, msgspec.inspect.NoneType)]
            if len(members) == 1:
                info = members[0]
                continue
        return info, extra


def _bounds(info: Any) -> tuple[float | None, float | None, bool]:
    lo = getattr(info, "ge", None)
    open_low = False
    if lo is None and getattr(info, "gt", None) is not None:
        lo, open_low = info.gt, True
    hi = getattr(info, "le", None)
    if hi is None:
        hi = getattr(info, "lt", None)
    return lo, hi, open_low


def _expected(info: Any) -> str:
    if isinstance(info, msgspec.inspect.FloatType):
        lo, hi, open_low = _bounds(info)
        return (
            f"a number in {number_range(lo, hi, open_low=open_low)}"
            if (lo, hi) != (None, None)
            else "a number"
        )
    if isinstance(info, msgspec.inspect.IntType):
        lo, hi, _ = _bounds(info)
        return f"an integer in [{lo}, {hi}]" if (lo, hi) != (None, None) else "an integer"
    if isinstance(info, msgspec.inspect.BoolType):
        return "true or false"
    if isinstance(info, msgspec.inspect.StrType):
        return "a non-empty string" if info.min_length else "a string"
    if isinstance(info, msgspec.inspect.LiteralType):
        return "one of " + ", ".join(str(v) for v in info.values)
    if _fields(info) is not None or isinstance(info, msgspec.inspect.DictType):
        return "a table"
    if isinstance(info, msgspec.inspect.ListType | msgspec.inspect.TupleType | msgspec.inspect.VarTupleType):
        return "a list"
    return "another type"


__all__ = [
    "FINITE",
    "NON_EMPTY",
    "UNKNOWN_KEYS_IGNORED",
    "Invalid",
    "OneOf",
    "above",
    "convert",
    "key_name",
    "number_range",
    "show",
    "within",
]
