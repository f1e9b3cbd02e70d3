"""Depth frames on the wire: what a camera node publishes reads back as the same image, and anything else is
refused with one line saying what is wrong."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from wire.depth import BadFrame, decode_depth, encode_depth

depths = arrays(
    np.float32,
    st.tuples(st.integers(1, 24), st.integers(1, 32)),
    elements=st.floats(0.0, 65.5, width=32),
)


@given(depth=depths, seq=st.integers(0, 2**40), t=st.floats(0.0, 2e9))
def test_a_frame_reads_back_to_the_millimetre(depth: np.ndarray, seq: int, t: float) -> None:
    payload, attachment = encode_depth(depth, seq=seq, t=t)
    header, back = decode_depth(payload, attachment)
    assert (header.height, header.width, header.seq, header.t) == (*depth.shape, seq, t)
    assert back.dtype == np.float32
    assert np.max(np.abs(back - depth), initial=0.0) <= 0.0005 + 1e-6


def test_no_reading_and_out_of_range_depth_are_zero() -> None:
    depth = np.array([[np.nan, -1.0, 70.0, 0.5]], dtype=np.float32)
    _, back = decode_depth(*encode_depth(depth, seq=0, t=0.0))
    assert back.tolist() == [[0.0, 0.0, float(np.float32(65.535)), 0.5]]


def header(**changes: object) -> bytes:
    base: dict[str, object] = {"encoding": "uint16_mm_le", "width": 2, "height": 1, "seq": 0, "t": 1.0}
    return json.dumps({**base, **changes}).encode()


@pytest.mark.parametrize(
    ("payload", "attachment", "message"),
    [
        (b"\0" * 4, None, "the sample has no attachment (the frame header)"),
        (b"\0" * 4, b"{", "the frame header is not JSON: Expecting property name enclosed in double quotes"),
        (b"\0" * 4, b"[1]", "the frame header is not a JSON object"),
        (b"\0" * 4, header(encoding="16UC1"), "frame encoding '16UC1' is not 'uint16_mm_le'"),
        (b"\0" * 4, header(width=0), "frame width 0 is not a whole number of pixels in 1..4096"),
        (b"\0" * 4, header(height=True), "frame height True is not a whole number of pixels in 1..4096"),
        (b"\0" * 4, header(width=5000), "frame width 5000 is not a whole number of pixels in 1..4096"),
        (b"\0" * 4, header(seq=-1), "frame seq -1 is not a whole number >= 0"),
        (b"\0" * 4, header(t="now"), "frame t 'now' is not a finite number of seconds"),
        (b"\0" * 3, header(), "frame has 3 bytes for 2x1 pixels (expected 4)"),
    ],
)
def test_a_malformed_sample_is_refused_saying_why(
    payload: bytes, attachment: bytes | None, message: str
) -> None:
    with pytest.raises(BadFrame) as err:
        decode_depth(payload, attachment)
    assert str(err.value).startswith(message)


def test_only_an_image_is_encoded() -> None:
    with pytest.raises(ValueError, match=r"a depth image has 2 dimensions, got shape \(2, 2, 1\)"):
        encode_depth(np.zeros((2, 2, 1)), seq=0, t=0.0)
