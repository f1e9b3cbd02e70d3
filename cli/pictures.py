"""Writing the pictures the verbs draw (``plan --png``, ``arm workspace --png``): whole or not at all, with
the mode any new file gets, and saying in words what they show.

A PNG carries PNG ``tEXt`` chunks (``Title``, ``Description``, ``Software``): the title, the units, the sizes
and the names drawn in it, so a reader without eyes (a search, ``exiftool``, a test) can tell what it shows.
"""

from __future__ import annotations

import os
import secrets
import struct
import zlib
from collections.abc import Mapping
from pathlib import Path

_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_with_text(png: bytes, text: Mapping[str, str]) -> bytes:
    """``png`` with a ``tEXt`` chunk per (keyword, text) after its header chunk (Latin-1; others replaced)."""
    if not png.startswith(_SIGNATURE) or png[12:16] != b"IHDR":
        raise ValueError("not a PNG: no signature and header chunk")
    header_end = 8 + 12 + struct.unpack(">I", png[8:12])[0]
    chunks = b"".join(
        _chunk(b"tEXt", key.encode("latin-1") + b"\0" + value.encode("latin-1", "replace"))
        for key, value in text.items()
    )
    return png[:header_end] + chunks + png[header_end:]


def png_text(png: bytes) -> dict[str, str]:
    """The ``tEXt`` chunks of a PNG, keyword to text."""
    out: dict[str, str] = {}
    at = len(_SIGNATURE)
    while at + 8 <= len(png):
        length, kind = struct.unpack(">I4s", png[at : at + 8])
        if kind == b"tEXt":
            key, _, value = png[at + 8 : at + 8 + length].partition(b"\0")
            out[key.decode("latin-1")] = value.decode("latin-1")
        at += 12 + length
    return out


def write_atomically(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file beside ``path``, then rename it over ``path``: a reader sees the old file
    or the new one. The file gets the mode any new file gets (0644 under the usual umask 022; ``mkstemp``'s
    0600 would hide a picture from the web server or the colleague it is for)."""
    tmp = path.parent.resolve() / f".{path.name}.{secrets.token_hex(6)}"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
