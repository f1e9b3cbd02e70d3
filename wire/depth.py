"""Depth frames on the wire: what a camera node publishes and the daemon's ``zenoh`` camera reads.

A frame is one Zenoh sample: the payload is the depth image itself, unsigned 16-bit millimetres,
little-endian, row-major (0 = no reading), as depth cameras deliver it; the attachment is a small JSON header
saying how to read it (``width``, ``height``, ``encoding``, and the node's frame number ``seq`` and capture
time ``t``, Unix seconds on the node's clock). Binary rather than JSON: a 640x480 frame is 600 KiB raw and
would be a third more in base64, several times a second.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

ENCODING: Final = "uint16_mm_le"
MAX_SIDE_PX: Final = 4096  # no depth camera dishbot knows of comes near it; bounds what a frame may ask for


class BadFrame(ValueError):
    """A depth sample that is not a frame of this format; the message says what is wrong with it."""


@dataclass(frozen=True, slots=True)
class FrameHeader:
    """What the attachment of a depth sample says."""

    width: int
    height: int
    seq: int
    t: float
    encoding: str = ENCODING

    def to_bytes(self) -> bytes:
        return json.dumps(
            {
                "encoding": self.encoding,
                "width": self.width,
                "height": self.height,
                "seq": self.seq,
                "t": self.t,
            },
            separators=(",", ":"),
        ).encode()

    @classmethod
    def from_bytes(cls, data: bytes | None) -> FrameHeader:
        if not data:
            raise BadFrame("the sample has no attachment (the frame header)")
        try:
            obj = json.loads(data)
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise BadFrame(f"the frame header is not JSON: {e}") from e
        if not isinstance(obj, dict):
            raise BadFrame("the frame header is not a JSON object")
        if obj.get("encoding") != ENCODING:
            raise BadFrame(f"frame encoding {obj.get('encoding')!r} is not {ENCODING!r}")
        seq, t = obj.get("seq", 0), obj.get("t", 0.0)
        if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
            raise BadFrame(f"frame seq {seq!r} is not a whole number >= 0")
        if not isinstance(t, int | float) or isinstance(t, bool) or not math.isfinite(t):
            raise BadFrame(f"frame t {t!r} is not a finite number of seconds")
        return cls(width=_side(obj, "width"), height=_side(obj, "height"), seq=seq, t=float(t))


def _side(header: dict[str, object], name: str) -> int:
    value = header.get(name)
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= MAX_SIDE_PX:
        raise BadFrame(f"frame {name} {value!r} is not a whole number of pixels in 1..{MAX_SIDE_PX}")
    return value


def encode_depth(depth_m: npt.NDArray[np.floating], *, seq: int, t: float) -> tuple[bytes, bytes]:
    """A depth image in metres (0 or NaN = no reading) as a sample's payload and attachment."""
    if depth_m.ndim != 2:
        raise ValueError(f"a depth image has 2 dimensions, got shape {depth_m.shape}")
    mm = np.nan_to_num(np.asarray(depth_m, dtype=np.float64) * 1000.0, nan=0.0, posinf=0.0, neginf=0.0)
    pixels = np.clip(np.rint(mm), 0, 65535).astype("<u2")
    height, width = pixels.shape
    return pixels.tobytes(), FrameHeader(width=width, height=height, seq=seq, t=t).to_bytes()


def decode_depth(payload: bytes, attachment: bytes | None) -> tuple[FrameHeader, npt.NDArray[np.float32]]:
    """The header and the depth image in metres (0 = no reading); ``BadFrame`` saying what is wrong."""
    header = FrameHeader.from_bytes(attachment)
    expected = 2 * header.width * header.height
    if len(payload) != expected:
        raise BadFrame(
            f"frame has {len(payload)} bytes for {header.width}x{header.height} pixels (expected {expected})"
        )
    pixels = np.frombuffer(payload, dtype="<u2").reshape(header.height, header.width)
    return header, pixels.astype(np.float32) / np.float32(1000.0)
