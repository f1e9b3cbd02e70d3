"""Byte-level codecs of the Dynamixel Protocol 1.0 and 2.0 packets.

Both the bus (for the reads the SDK gets wrong: bulk read on 1.0 and the status error byte of sync read) and
the pseudo-terminal servo simulator use these functions, so a packet is framed, checksummed and parsed the
same way on both ends of the simulated wire. Everything here is pure: bytes in, values out.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Final, Literal

Protocol = Literal[1, 2]

BROADCAST_ID: Final = 0xFE
MAX_ID: Final = 0xFC  # 252, the highest id a servo can take

HEADER_1: Final = b"\xff\xff"
HEADER_2: Final = b"\xff\xff\xfd\x00"

# Instructions shared by both protocols (2.0-only ones are marked).
PING: Final = 0x01
READ: Final = 0x02
WRITE: Final = 0x03
REG_WRITE: Final = 0x04
ACTION: Final = 0x05
FACTORY_RESET: Final = 0x06
REBOOT: Final = 0x08  # 2.0 (and recent 1.0 firmware; the thesis's servos ignore it)
STATUS: Final = 0x55  # 2.0: the instruction byte of a status packet
SYNC_READ: Final = 0x82  # 2.0
SYNC_WRITE: Final = 0x83
BULK_READ: Final = 0x92

# A 1.0 length byte can be at most 255; a 2.0 packet longer than this is garbage for every servo we drive.
MAX_PARAMS_2: Final = 1024


@dataclass(frozen=True, slots=True)
class Frame:
    """One checksummed packet as it was on the wire, header and checksum removed (2.0: unstuffed).

    ``code`` is the instruction of an instruction packet; in a 1.0 status packet it is the error byte, in a
    2.0 status packet it is ``STATUS`` and the error byte is ``params[0]``.
    """

    servo_id: int
    code: int
    params: bytes


@dataclass(frozen=True, slots=True)
class Status:
    """A servo's answer: its id, the error byte and the data it returned."""

    servo_id: int
    error: int
    data: bytes


# ---------------------------------------------------------------------------------------------- checksums


def checksum_1(body: Iterable[int]) -> int:
    """Protocol 1.0 checksum over id, length, instruction/error and parameters."""
    return ~sum(body) & 0xFF


def _crc_table() -> tuple[int, ...]:
    table = []
    for n in range(256):
        crc = n << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE: Final = _crc_table()


def crc16(data: bytes | bytearray) -> int:
    """Protocol 2.0 CRC-16 (polynomial 0x8005, initial value 0, not reflected) over header to parameters."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(payload: bytes) -> bytes:
    """Insert 0xFD after every FF FF FD in the instruction+parameter field so it cannot look like a header."""
    out = bytearray()
    run = 0  # how many bytes of FF FF FD the tail of ``out`` matches
    for byte in payload:
        out.append(byte)
        if run == 2 and byte == 0xFD:
            out.append(0xFD)
            run = 0
        elif byte == 0xFF:
            run = 2 if run >= 1 else 1
        else:
            run = 0
    return bytes(out)


def unstuff(payload: bytes) -> bytes:
    """Undo :func:`stuff`: drop the 0xFD that follows every FF FF FD."""
    out = bytearray()
    i = 0
    while i < len(payload):
        out.append(payload[i])
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd" and i + 1 < len(payload) and payload[i + 1] == 0xFD:
            i += 1
        i += 1
    return bytes(out)


# ---------------------------------------------------------------------------------------------- encoding


def encode(protocol: Protocol, servo_id: int, code: int, params: bytes = b"") -> bytes:
    """A complete packet: header, id, length, instruction (or 1.0 error byte), parameters and checksum."""
    if not 0 <= servo_id <= 0xFE:
        raise ValueError(f"servo id {servo_id} is outside 0..254")
    if protocol == 1:
        if len(params) > 253:
            raise ValueError(f"a Protocol 1.0 packet carries at most 253 parameter bytes, got {len(params)}")
        body = bytes((servo_id, len(params) + 2, code)) + params
        return HEADER_1 + body + bytes((checksum_1(body),))
    payload = stuff(bytes((code,)) + params)
    length = len(payload) + 2
    packet = HEADER_2 + bytes((servo_id, length & 0xFF, length >> 8)) + payload
    crc = crc16(packet)
    return packet + bytes((crc & 0xFF, crc >> 8))


def encode_status(protocol: Protocol, servo_id: int, error: int, data: bytes = b"") -> bytes:
    """A status packet as a servo sends it."""
    if protocol == 1:
        return encode(1, servo_id, error, data)
    return encode(2, servo_id, STATUS, bytes((error,)) + data)


def le(value: int, size: int) -> bytes:
    """``value`` as ``size`` little-endian bytes (two's complement for negatives)."""
    return (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


def from_le(data: bytes, *, signed: bool = False) -> int:
    """A little-endian integer."""
    return int.from_bytes(data, "little", signed=signed)


def ping(protocol: Protocol, servo_id: int) -> bytes:
    return encode(protocol, servo_id, PING)


def read(protocol: Protocol, servo_id: int, address: int, length: int) -> bytes:
    if protocol == 1:
        return encode(1, servo_id, READ, bytes((address, length)))
    return encode(2, servo_id, READ, le(address, 2) + le(length, 2))


def write(protocol: Protocol, servo_id: int, address: int, data: bytes) -> bytes:
    addr = bytes((address,)) if protocol == 1 else le(address, 2)
    return encode(protocol, servo_id, WRITE, addr + data)


def sync_write(protocol: Protocol, address: int, length: int, items: Sequence[tuple[int, bytes]]) -> bytes:
    """One broadcast packet writing ``length`` bytes at ``address`` of every listed servo."""
    head = bytes((address, length)) if protocol == 1 else le(address, 2) + le(length, 2)
    body = bytearray(head)
    for servo_id, data in items:
        if len(data) != length:
            raise ValueError(f"sync write to servo {servo_id}: {len(data)} data bytes, expected {length}")
        body.append(servo_id)
        body += data
    return encode(protocol, BROADCAST_ID, SYNC_WRITE, bytes(body))


def bulk_read_1(items: Sequence[tuple[int, int, int]]) -> bytes:
    """Protocol 1.0 bulk read of (servo_id, address, length) blocks; the servos answer in this order."""
    body = bytearray((0x00,))
    for servo_id, address, length in items:
        body += bytes((length, servo_id, address))
    return encode(1, BROADCAST_ID, BULK_READ, bytes(body))


def sync_read_2(address: int, length: int, servo_ids: Sequence[int]) -> bytes:
    """Protocol 2.0 sync read of the same block from every listed servo; they answer in this order."""
    return encode(2, BROADCAST_ID, SYNC_READ, le(address, 2) + le(length, 2) + bytes(servo_ids))


# ---------------------------------------------------------------------------------------------- decoding


class Framer:
    """Cuts a byte stream into checksummed frames; noise, torn and corrupt packets are skipped and counted.

    A frame is only returned when its checksum (1.0) or CRC (2.0) matches, so a corrupted value is never
    handed to the caller. Bytes of a packet that has not fully arrived stay buffered for the next ``feed``.
    """

    def __init__(self, protocol: Protocol) -> None:
        self.protocol: Protocol = protocol
        self._buf = bytearray()
        self.corrupt = 0  # packets dropped for a bad checksum or an impossible length

    def feed(self, data: bytes) -> list[Frame]:
        self._buf += data
        if self.protocol == 1:
            return self._feed_1()
        frames: list[Frame] = []
        while True:
            frame, done = self._next()
            if frame is not None:
                frames.append(frame)
            if done:
                return frames

    def pending(self) -> int:
        """Bytes held back, waiting for the rest of a packet."""
        return len(self._buf)

    def _next(self) -> tuple[Frame | None, bool]:
        header = HEADER_1 if self.protocol == 1 else HEADER_2
        start = self._buf.find(header)
        if start < 0:
            # Keep a tail that may be the beginning of a header.
            keep = len(header) - 1
            del self._buf[: max(0, len(self._buf) - keep)]
            while self._buf and not header.startswith(bytes(self._buf)):
                del self._buf[0]
            return None, True
        del self._buf[:start]
        return self._frame_1() if self.protocol == 1 else self._frame_2()

    def _feed_1(self) -> list[Frame]:
        """``feed`` on Protocol 1.0 in one pass over the buffer: the frames ``_next`` would cut one at a time
        (the same frames, corrupt count and bytes kept), deleting what was consumed once at the end."""
        buf = self._buf
        n = len(buf)
        frames: list[Frame] = []
        pos = 0
        while True:
            start = buf.find(HEADER_1, pos)
            if start < 0:
                # Keep a tail that may be the beginning of a header (a last 0xFF).
                pos = n - 1 if pos < n and buf[n - 1] == 0xFF else n
                break
            if n - start < 4:
                pos = start
                break
            servo_id, length = buf[start + 2], buf[start + 3]
            if servo_id == 0xFF or length < 2:
                # FF FF FF ... : the header may start one byte later; not a packet here.
                pos = start + 1
                continue
            end = start + 4 + length
            if n < end:
                pos = start
                break
            if ~sum(buf[start + 2 : end - 1]) & 0xFF != buf[end - 1]:
                self.corrupt += 1
                pos = start + 1
                continue
            frames.append(Frame(servo_id, buf[start + 4], bytes(buf[start + 5 : end - 1])))
            pos = end
        if pos:
            del buf[:pos]
        return frames

    def _drop_header_byte(self) -> tuple[None, bool]:
        self.corrupt += 1
        del self._buf[0]
        return None, False

    def _frame_1(self) -> tuple[Frame | None, bool]:
        buf = self._buf
        if len(buf) < 4:
            return None, True
        servo_id, length = buf[2], buf[3]
        if servo_id == 0xFF or length < 2:
            # FF FF FF ... : the header may start one byte later; not a packet here.
            del buf[0]
            return None, False
        total = 4 + length
        if len(buf) < total:
            return None, True
        body = bytes(buf[2 : total - 1])
        if checksum_1(body) != buf[total - 1]:
            return self._drop_header_byte()
        del buf[:total]
        return Frame(servo_id, body[2], body[3:]), False

    def _frame_2(self) -> tuple[Frame | None, bool]:
        buf = self._buf
        if len(buf) < 7:
            return None, True
        servo_id = buf[4]
        length = buf[5] | (buf[6] << 8)
        if servo_id == 0xFF or length < 3 or length > MAX_PARAMS_2 + 3:
            return self._drop_header_byte()
        total = 7 + length
        if len(buf) < total:
            return None, True
        crc = buf[total - 2] | (buf[total - 1] << 8)
        if crc16(bytes(buf[: total - 2])) != crc:
            return self._drop_header_byte()
        payload = unstuff(bytes(buf[7 : total - 2]))
        del buf[:total]
        return Frame(servo_id, payload[0], payload[1:]), False


def as_status(protocol: Protocol, frame: Frame) -> Status | None:
    """The status carried by ``frame``, or None when it is an instruction packet (or a torn 2.0 status)."""
    if protocol == 1:
        return Status(frame.servo_id, frame.code, frame.params)
    if frame.code != STATUS or not frame.params:
        return None
    return Status(frame.servo_id, frame.params[0], frame.params[1:])
