"""Protocol 1.0 framing, shared by Dynamixel AX/MX (P1 firmware) and Feetech STS/SCS.

Wire format::

    instruction  FF FF  ID  LEN  INST  params...  CHK
    status       FF FF  ID  LEN  ERR   params...  CHK

``LEN`` = number of params + 2; ``CHK = ~(ID + LEN + INST|ERR + sum(params)) & 0xFF``. No byte
stuffing, no CRC: the 8-bit checksum is the only integrity check. Broadcast ID 0xFE gets no
status packet. Sources: DynamixelSDK ``protocol1_packet_handler.py`` (txPacket) and Feetech's
``scservo_sdk/protocol_packet_handler.py`` (the same framing); instruction codes from
``robotis_def.py`` and ``scservo_def.py``.

Group instructions (all broadcast, ``ID = FE``)::

    SYNC WRITE 0x83   addr len  [id data(len)] x N           every family
    SYNC READ  0x82   addr len  id1 ... idN                  Feetech STS/SMS only: each servo
                                                              answers with its own status packet
    BULK READ  0x92   00  [len id addr] x N                  Dynamixel MX (P1) only
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
#: Highest unicast ID (Dynamixel P1: 0..253; Feetech's SDK stops at 252, MAX_ID 0xFC).
MAX_ID = 0xFD
#: Largest packet the SDKs handle (TXPACKET_MAX_LEN = RXPACKET_MAX_LEN = 250).
MAX_PACKET_BYTES = 250
#: Bytes of a packet with no params: FF FF ID LEN INST|ERR CHK.
OVERHEAD = 6


class Inst(IntEnum):
    """Instruction codes (``robotis_def.py``, ``scservo_def.py``)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RESET = 0x06  # Dynamixel FACTORY_RESET; Feetech RESET
    SYNC_READ = 0x82  # Feetech STS/SMS
    SYNC_WRITE = 0x83
    BULK_READ = 0x92  # Dynamixel MX (P1)


def checksum(body: bytes | bytearray | Iterable[int]) -> int:
    """``~sum(body) & 0xFF``; ``body`` is ID through the last param."""
    return ~sum(body) & 0xFF


def _frame(packet_id: int, code: int, params: bytes) -> bytes:
    if not 0 <= packet_id <= 0xFE:
        raise ValueError(f"packet ID must be 0..254, got {packet_id}")
    if len(params) + OVERHEAD > MAX_PACKET_BYTES:
        raise ValueError(f"{len(params)} params: over the {MAX_PACKET_BYTES}-byte packet limit")
    body = bytes((packet_id, len(params) + 2, code)) + bytes(params)
    return HEADER + body + bytes((checksum(body),))


def encode_instruction(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet: ``FF FF ID LEN INST params CHK``."""
    return _frame(packet_id, instruction, params)


def encode_status(packet_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet: ``FF FF ID LEN ERR params CHK``."""
    return _frame(packet_id, error, params)


def ping(packet_id: int) -> bytes:
    """PING: ``ping(1) == FF FF 01 02 01 FB``."""
    return encode_instruction(packet_id, Inst.PING)


def read(packet_id: int, addr: int, length: int) -> bytes:
    """READ ``length`` bytes at ``addr``: ``read(1, 56, 2) == FF FF 01 04 02 38 02 BE``."""
    return encode_instruction(packet_id, Inst.READ, bytes((addr, length)))


def write(packet_id: int, addr: int, data: bytes) -> bytes:
    """WRITE ``data`` at ``addr``."""
    return encode_instruction(packet_id, Inst.WRITE, bytes((addr,)) + bytes(data))


def sync_write(addr: int, length: int, data_by_id: dict[int, bytes]) -> bytes:
    """SYNC WRITE (broadcast): ``addr len [id data] x N``; every data must be ``length`` bytes."""
    params = bytearray((addr, length))
    for sid, data in data_by_id.items():
        if len(data) != length:
            raise ValueError(f"ID {sid}: {len(data)} bytes of data, the packet says {length}")
        params.append(sid)
        params += data
    return encode_instruction(BROADCAST_ID, Inst.SYNC_WRITE, bytes(params))


def sync_read(addr: int, length: int, ids: Iterable[int]) -> bytes:
    """Feetech SYNC READ: ``sync_read(56, 2, [1, 2]) == FF FF FE 06 82 38 02 01 02 3C``."""
    return encode_instruction(BROADCAST_ID, Inst.SYNC_READ, bytes((addr, length, *ids)))


def bulk_read(items: Iterable[tuple[int, int, int]]) -> bytes:
    """Dynamixel MX BULK READ of ``(id, addr, length)`` items: ``00 [len id addr] x N``."""
    params = bytearray((0,))
    for sid, addr, length in items:
        params += bytes((length, sid, addr))
    return encode_instruction(BROADCAST_ID, Inst.BULK_READ, bytes(params))


def parse_sync_write(params: bytes) -> tuple[int, dict[int, bytes]] | None:
    """``(addr, {id: data})`` of SYNC WRITE params, or None if they do not add up."""
    if len(params) < 2:
        return None
    addr, length = params[0], params[1]
    body = params[2:]
    if length == 0 or len(body) % (length + 1):
        return None
    step = length + 1
    return addr, {body[i]: bytes(body[i + 1 : i + step]) for i in range(0, len(body), step)}


def parse_sync_read(params: bytes) -> tuple[int, int, list[int]] | None:
    """``(addr, length, ids)`` of SYNC READ params, or None."""
    if len(params) < 3 or params[1] == 0:
        return None
    return params[0], params[1], list(params[2:])


def parse_bulk_read(params: bytes) -> list[tuple[int, int, int]] | None:
    """``[(id, addr, length)]`` of BULK READ params (first byte 00), or None."""
    if len(params) < 4 or (len(params) - 1) % 3:
        return None
    return [(params[i + 1], params[i + 2], params[i]) for i in range(1, len(params), 3)]


@dataclass(frozen=True, slots=True)
class Packet:
    """A decoded packet: ``code`` is INST (instruction) or ERR (status)."""

    id: int
    code: int
    params: bytes = b""

    def encode(self) -> bytes:
        return _frame(self.id, self.code, self.params)


class PacketError(ValueError):
    """Bytes that are not one well-formed Protocol 1.0 packet."""


def decode(frame: bytes) -> Packet:
    """One whole packet (header to checksum); PacketError naming what is wrong."""
    if len(frame) < OVERHEAD or frame[:2] != HEADER:
        raise PacketError(f"not a Protocol 1.0 packet: {frame.hex(' ')}")
    length = frame[3]
    if length < 2 or len(frame) != length + 4:
        raise PacketError(f"LEN {length} does not match {len(frame)} bytes")
    if checksum(frame[2:-1]) != frame[-1]:
        raise PacketError(f"checksum {frame[-1]:02X}, expected {checksum(frame[2:-1]):02X}")
    return Packet(frame[2], frame[4], bytes(frame[5:-1]))


def split_status_stream(data: bytes) -> list[Packet]:
    """Consecutive status packets (a Sync/Bulk Read's replies) as packets; PacketError if
    the bytes are not exactly a run of whole, valid packets."""
    out = []
    i = 0
    while i < len(data):
        if len(data) - i < OVERHEAD:
            raise PacketError(f"{len(data) - i} trailing bytes")
        n = data[i + 3] + 4
        out.append(decode(data[i : i + n]))
        i += n
    return out


#: A frame from :meth:`StreamParser.feed_decoded`: raw, id, checksum_ok, code, params.
Decoded = tuple[bytes, int, bool, int, bytes]


class StreamParser:
    """Cut packets out of a byte stream, resynchronising after garbage.

    Feed bytes as they arrive; complete frames come back in order as ``(end, decoded)``,
    ``end`` being the stream index one past the frame (so a caller knowing each byte's time
    knows when the packet was complete). A header ``FF FF`` followed by ID ``FF`` is taken as
    one stray ``FF`` (IDs stop at 0xFE); a LEN below 2 drops the header's first byte.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._base = 0
        self.skipped = 0

    @property
    def pending(self) -> int:
        """Bytes held that do not yet form a complete frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop a partial frame (the servo's inter-byte timeout)."""
        self._drop(len(self._buf))

    def feed_decoded(self, data: bytes) -> list[tuple[int, Decoded]]:
        buf = self._buf
        buf += data
        frames: list[tuple[int, Decoded]] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                self._drop(len(buf) - (1 if buf.endswith(b"\xff") else 0))
                return frames
            self._drop(start)
            if len(buf) < 4:
                return frames
            if buf[2] == 0xFF or buf[3] < 2:
                self._drop(1)
                continue
            total = buf[3] + 4
            if len(buf) < total:
                return frames
            raw = bytes(buf[:total])
            del buf[:total]
            self._base += total
            ok = checksum(raw[2:-1]) == raw[-1]
            frames.append((self._base, (raw, raw[2], ok, raw[4], raw[5:-1] if ok else b"")))

    def feed(self, data: bytes) -> list[Packet | None]:
        """Complete frames as packets (None where the checksum failed)."""
        return [
            Packet(fid, code, params) if ok else None
            for _, (_, fid, ok, code, params) in self.feed_decoded(data)
        ]

    def _drop(self, n: int) -> None:
        if n > 0:
            del self._buf[:n]
            self._base += n
            self.skipped += n
