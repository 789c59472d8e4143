"""Dynamixel Protocol 2.0 framing: CRC-16, byte stuffing, packet encode/decode, stream parsing.

Wire format (all multi-byte fields little endian)::

    instruction  FF FF FD 00  ID  LEN_L LEN_H  INST       params...  CRC_L CRC_H
    status       FF FF FD 00  ID  LEN_L LEN_H  55   ERR  params...  CRC_L CRC_H

``LEN`` counts INST (+ERR) + params (after stuffing) + the two CRC bytes. Inside
INST..params every ``FF FF FD`` is sent as ``FF FF FD FD``. The CRC (poly 0x8005,
init 0, MSB first, unreflected) covers the header through the last (stuffed)
parameter byte.

This module is shared by both ends: the emulator decodes instruction packets and
encodes status packets; tests and tools do the reverse. It knows nothing about
servos, timing or ports.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from drivers.protocol2 import control_table as _ct
from drivers.protocol2.crc import crc16 as crc16  # re-exported: the codec's CRC

# The error numbers are the same at both ends of the wire: one definition, in the driver's data.
ErrorCode = _ct.StatusError
ALERT_BIT = _ct.ALERT_BIT

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
#: Largest LEN we accept (the SDK's own buffers are 1024 bytes).
MAX_LENGTH = 1024
#: Bytes in a packet that carries no parameters: header(4) + ID + LEN(2) + INST + CRC(2).
INSTRUCTION_OVERHEAD = 10
STATUS_OVERHEAD = 11


class Instruction(IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    BACKUP = 0x20
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


def stuff(body: bytes) -> bytes:
    """Insert a 0xFD after every ``FF FF FD`` in ``body`` (INST..params).

    The two bytes before ``body`` on the wire are LEN_L LEN_H, which can end in FF FF
    only if LEN >= 0xFFFF, so the search may stay inside ``body``.
    """
    if b"\xff\xff\xfd" not in body:
        return body
    out = bytearray()
    i = 0
    while (j := body.find(b"\xff\xff\xfd", i)) >= 0:
        out += body[i : j + 3]
        out.append(0xFD)
        i = j + 3
    out += body[i:]
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Inverse of :func:`stuff`: every ``FF FF FD FD`` becomes ``FF FF FD``."""
    if b"\xff\xff\xfd\xfd" not in body:
        return body
    return body.replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


def _frame(packet_id: int, body: bytes) -> bytes:
    body = stuff(body)
    length = len(body) + 2
    head = HEADER + bytes((packet_id, length & 0xFF, length >> 8))
    crc = crc16(body, crc16(head))
    return head + body + bytes((crc & 0xFF, crc >> 8))


def encode_instruction(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """One instruction packet, stuffed and CRC'd, ready for the wire."""
    if not 0 <= packet_id <= 0xFE:
        raise ValueError(f"packet id must be 0..254, got {packet_id}")
    return _frame(packet_id, bytes((instruction,)) + bytes(params))


def encode_status(packet_id: int, error: int, params: bytes = b"") -> bytes:
    """One status packet (instruction 0x55), stuffed and CRC'd."""
    return _frame(packet_id, bytes((Instruction.STATUS, error)) + bytes(params))


def encode_fast_status(blocks: list[tuple[int, int, bytes]], length: int | None = None) -> bytes:
    """The single reply to Fast Sync Read / Fast Bulk Read.

    ``blocks`` is ``[(error, id, data), ...]`` in the order the instruction listed the IDs.
    Layout: header, ID 0xFE, LEN, 0x55, then per servo ``ERR ID data CRC_L CRC_H``, where
    each block's CRC is the running CRC over the packet from its first byte to the end of
    that block's data. The first block's ERR sits in the header's ERR slot. Never stuffed.
    ``length`` overrides the LEN field: the first servo announces every block it was asked
    for, even when later servos then fail to append theirs.
    """
    if not blocks:
        raise ValueError("a fast status packet needs at least one block")
    if length is None:
        length = 1 + sum(len(data) + 4 for _, _, data in blocks)  # INST + blocks
    out = bytearray(HEADER)
    out += bytes((BROADCAST_ID, length & 0xFF, length >> 8, Instruction.STATUS))
    crc = crc16(out)
    for error, servo_id, data in blocks:
        start = len(out)
        out.append(error)
        out.append(servo_id)
        out += data
        crc = crc16(memoryview(out)[start:], crc)
        out.append(crc & 0xFF)
        out.append(crc >> 8)
        crc = crc16(memoryview(out)[-2:], crc)
    return bytes(out)


class PacketError(ValueError):
    """A frame that is not a valid Protocol 2.0 packet (bad header, length or CRC)."""


@dataclass(frozen=True, slots=True)
class Packet:
    """A decoded packet. ``error`` is None for instruction packets."""

    id: int
    instruction: int
    params: bytes
    error: int | None = None

    def encode(self) -> bytes:
        if self.error is None:
            return encode_instruction(self.id, self.instruction, self.params)
        return encode_status(self.id, self.error, self.params)


def decode(frame: bytes) -> Packet:
    """Decode one complete frame (header through CRC); raise :class:`PacketError` if invalid.

    Fast Sync/Bulk Read replies (ID 0xFE status) are returned with their raw block bytes
    as ``params`` (everything after the first ERR), since they are never stuffed.
    """
    frame = bytes(frame)
    if len(frame) < INSTRUCTION_OVERHEAD or not frame.startswith(HEADER):
        raise PacketError("no packet header")
    length = frame[5] | frame[6] << 8
    if length < 3 or len(frame) != 7 + length:
        raise PacketError(f"length field {length} does not match a {len(frame)}-byte frame")
    crc = frame[-2] | frame[-1] << 8
    if crc16(frame[:-2]) != crc:
        raise PacketError(f"CRC mismatch: got {crc:#06x}, expected {crc16(frame[:-2]):#06x}")
    packet_id = frame[4]
    instruction = frame[7]
    if instruction != Instruction.STATUS:
        return Packet(packet_id, instruction, unstuff(frame[8:-2]))
    if length < 4:
        raise PacketError("status packet without an ERR byte")
    if packet_id == BROADCAST_ID:  # fast read reply: not stuffed, blocks follow
        return Packet(packet_id, instruction, frame[9:-2], frame[8])
    return Packet(packet_id, instruction, unstuff(frame[9:-2]), frame[8])


@dataclass(frozen=True, slots=True)
class Frame:
    """A complete frame cut from a byte stream, valid or not.

    ``end`` is the index (in the stream fed so far) one past the frame's last byte, so a
    caller that knows when each byte arrived knows when the packet was complete.
    ``packet`` is None when the CRC failed (``crc_ok`` False); ``id`` is still the ID
    byte as received, which is what a real servo uses to decide whether to complain.
    """

    id: int
    end: int
    crc_ok: bool
    packet: Packet | None
    raw: bytes


#: A frame as :meth:`StreamParser.feed_decoded` gives it: raw, id, crc_ok, instruction, params.
Decoded = tuple[bytes, int, bool, int, bytes]
_DECODED_KEPT = 64  # frames StreamParser remembers decoded


class StreamParser:
    """Cut instruction frames out of a byte stream, resynchronising after garbage.

    Feed bytes as they arrive; complete frames come back in order. Bytes that cannot
    start a packet are skipped; a frame whose length field is impossible is abandoned
    one byte past its header and the search resumes. A partial frame can be dropped
    with :meth:`reset` (the servos' inter-byte timeout).
    """

    def __init__(self, max_length: int = MAX_LENGTH) -> None:
        self._buf = bytearray()
        self._base = 0  # stream index of _buf[0]
        self.max_length = max_length
        self.skipped = 0  # bytes discarded while hunting for a header
        self._decoded: dict[bytes, Decoded] = {}  # frames seen lately, see feed_decoded

    @property
    def pending(self) -> int:
        """Bytes held that do not yet form a complete frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop any partial frame (the servo's 1.5 ms inter-byte timeout)."""
        self._base += len(self._buf)
        self.skipped += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes) -> list[Frame]:
        return [
            Frame(fid, end, ok, Packet(fid, inst, params) if ok else None, raw)
            for end, (raw, fid, ok, inst, params) in self.feed_decoded(data)
        ]

    def feed_decoded(self, data: bytes) -> list[tuple[int, Decoded]]:
        """:meth:`feed` without the objects: each frame as ``(end, (raw, id, crc_ok,
        instruction, params))``, ``params`` unstuffed (``b""`` when the CRC failed), as
        :class:`Frame` and :class:`Packet` would hold them (the emulator's bus takes this,
        every packet). The same bytes decode the same way, so a frame seen lately (a host
        sends the same Sync Read every tick) is looked up, not decoded again."""
        buf = self._buf
        if not buf and data[:4] == HEADER and len(data) >= 7:
            # The usual case: nothing held, and ``data`` is exactly one frame. The loop below
            # would find the header at 0, take the whole of ``data`` and then hold nothing.
            length = data[5] | data[6] << 8
            total = 7 + length
            if total == len(data) and 3 <= length <= self.max_length:
                self._base += total
                return [(self._base, self._decode(bytes(data)))]
        buf += data
        frames: list[tuple[int, Decoded]] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # Keep a possible header prefix (FF, FF FF, FF FF FD) for the next feed.
                keep = 0
                for k in (3, 2, 1):
                    if buf.endswith(HEADER[:k]):
                        keep = k
                        break
                self._drop(len(buf) - keep)
                return frames
            if start:
                self._drop(start)
            if len(buf) < 7:
                return frames
            length = buf[5] | buf[6] << 8
            if length < 3 or length > self.max_length:
                self._drop(1)  # not a real header: resume the search after its first byte
                continue
            total = 7 + length
            if len(buf) < total:
                return frames
            raw = bytes(buf[:total])
            end = self._base + total
            del buf[:total]
            self._base += total
            frames.append((end, self._decode(raw)))

    def _decode(self, raw: bytes) -> Decoded:
        decoded = self._decoded.get(raw)
        if decoded is None:
            crc_ok = crc16(raw[:-2]) == (raw[-2] | raw[-1] << 8)
            decoded = (raw, raw[4], crc_ok, raw[7], unstuff(raw[8:-2]) if crc_ok else b"")
            if len(self._decoded) >= _DECODED_KEPT:
                self._decoded.clear()
            self._decoded[raw] = decoded
        return decoded

    def _drop(self, n: int) -> None:
        if n > 0:
            del self._buf[:n]
            self._base += n
            self.skipped += n


def parse_fast_status(frame: bytes, data_lengths: list[int]) -> list[tuple[int, int, bytes, bool]]:
    """Split a Fast Sync/Bulk Read reply into ``[(error, id, data, crc_ok), ...]``.

    ``data_lengths`` gives each block's data size in order (all equal for Fast Sync Read).
    Raises :class:`PacketError` if the frame is not a fast reply of that shape.
    """
    frame = bytes(frame)
    expected = 8 + sum(n + 4 for n in data_lengths)
    if len(frame) != expected or not frame.startswith(HEADER) or frame[4] != BROADCAST_ID:
        raise PacketError(f"not a fast status reply of {expected} bytes")
    if frame[7] != Instruction.STATUS:
        raise PacketError("not a status packet")
    blocks = []
    i = 8
    crc = crc16(frame[:8])
    for n in data_lengths:
        crc = crc16(frame[i : i + 2 + n], crc)
        got = frame[i + 2 + n] | frame[i + 3 + n] << 8
        blocks.append((frame[i], frame[i + 1], frame[i + 2 : i + 2 + n], got == crc))
        crc = crc16(frame[i + 2 + n : i + 4 + n], crc)
        i += n + 4
    return blocks


def split_status_stream(data: bytes) -> list[Packet]:
    """Decode every valid status packet in ``data`` (host side helper for tests and tools)."""
    out = []
    i = 0
    while (start := data.find(HEADER, i)) >= 0:
        if start + 7 > len(data):
            break
        total = 7 + (data[start + 5] | data[start + 6] << 8)
        try:
            out.append(decode(data[start : start + total]))
            i = start + total
        except PacketError:
            i = start + 1
    return out
