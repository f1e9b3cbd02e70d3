"""The FSR sketch's line format and the resistor model that turns ADC counts into newtons.

Lines are ``$FSR,<seq>,<raw>*HH`` at 100 Hz and ``$VER,dishbot_fsr,<version>*HH`` in answer to ``?V``;
HH is the XOR of the characters between ``$`` and ``*`` (see ``arduino/dishbot_fsr.ino``). A line is only
accepted when its checksum, field count and ranges all hold, so line noise never becomes a force.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from description.thesis import FSR_PULLDOWN_OHM

VERSION_QUERY: Final = b"?V\n"
SKETCH_NAME: Final = "dishbot_fsr"
ADC_MAX: Final = 1023
SEQ_MODULO: Final = 65536
MAX_LINE: Final = 64  # longer runs without a newline are noise
_HEX_DIGITS: Final = frozenset("0123456789ABCDEF")

# Interlink FSR 400-series force/conductance curve (datasheet, typical): about 80 µS per newton up to 1 mS,
# then about 30 µS per newton. Per-pad differences are absorbed by the calibrated gain.
_US_PER_N_LOW: Final = 80.0
_US_PER_N_HIGH: Final = 30.0
_KNEE_US: Final = 1000.0


@dataclass(frozen=True, slots=True)
class Sample:
    seq: int
    raw: int


@dataclass(frozen=True, slots=True)
class Version:
    sketch: str
    version: str


def checksum(body: str) -> int:
    value = 0
    for char in body.encode("ascii"):
        value ^= char
    return value


def frame(body: str) -> bytes:
    """A complete line as the sketch sends it."""
    return f"${body}*{checksum(body):02X}\r\n".encode("ascii")


def sample_line(seq: int, raw: int) -> bytes:
    return frame(f"FSR,{seq % SEQ_MODULO},{raw}")


def version_line(version: str = "1") -> bytes:
    return frame(f"VER,{SKETCH_NAME},{version}")


def parse_line(line: bytes) -> Sample | Version | None:
    """A sample or version from one line (without its line ending), or None when it is not a valid line."""
    try:
        text = line.decode("ascii").strip()
    except UnicodeDecodeError:
        return None
    if len(text) < 4 or text[0] != "$" or text[-3] != "*":
        return None
    body, digits = text[1:-3], text[-2:]  # two characters: text[-3] is the star
    if digits[0] not in _HEX_DIGITS or digits[1] not in _HEX_DIGITS or int(digits, 16) != checksum(body):
        return None
    fields = body.split(",")
    if fields[0] == "FSR" and len(fields) == 3:
        seq_text, raw_text = fields[1], fields[2]
        if not (seq_text.isdigit() and len(seq_text) <= 5 and raw_text.isdigit() and len(raw_text) <= 5):
            return None
        seq, raw = int(seq_text), int(raw_text)
        if seq < SEQ_MODULO and raw <= ADC_MAX:
            return Sample(seq, raw)
        return None
    if fields[0] == "VER" and len(fields) == 3 and fields[1] == SKETCH_NAME and fields[2]:
        return Version(fields[1], fields[2])
    return None


def force_from_raw(raw: int, *, gain: float = 1.0, pulldown_ohm: float = FSR_PULLDOWN_OHM) -> float:
    """Newtons on the pad for an ADC reading of the divider (FSR on top, pull-down to ground)."""
    if raw <= 0:
        return 0.0
    raw = min(raw, ADC_MAX - 1)  # a saturated ADC means at least this much
    resistance = pulldown_ohm * (ADC_MAX - raw) / raw
    conductance_us = 1e6 / resistance
    if conductance_us <= _KNEE_US:
        force = conductance_us / _US_PER_N_LOW
    else:
        force = _KNEE_US / _US_PER_N_LOW + (conductance_us - _KNEE_US) / _US_PER_N_HIGH
    return force * gain


def raw_from_force(force_n: float, *, pulldown_ohm: float = FSR_PULLDOWN_OHM) -> int:
    """The ADC reading a force produces (inverse of :func:`force_from_raw` at gain 1; for the simulator)."""
    if force_n <= 0:
        return 0
    knee_n = _KNEE_US / _US_PER_N_LOW
    if force_n <= knee_n:
        conductance_us = force_n * _US_PER_N_LOW
    else:
        conductance_us = _KNEE_US + (force_n - knee_n) * _US_PER_N_HIGH
    resistance = 1e6 / conductance_us
    return min(ADC_MAX - 1, max(0, round(ADC_MAX * pulldown_ohm / (pulldown_ohm + resistance))))
