"""DMX over UDP: our own readers of E1.31 (sACN) data and sync packets and Art-Net ArtDmx/ArtSync.

Both formats are fixed layouts (``docs/live.md``, sACN and Art-Net, gives the offsets):

- **E1.31** (ANSI E1.31, "Streaming ACN"): a root layer (preamble 0x0010, "ASC-E1.17", vector 4
  for data or 8 for extended, the sender's 16-byte CID), a framing layer (source name,
  priority 0..200, sync address, sequence, options, universe 1..63999) and a DMP layer (start
  code, then up to 512 slots). An extended packet with framing vector 1 is a universe sync
  (sequence, sync address); other extended packets (discovery) are valid and unused.
- **Art-Net** ArtDmx (OpCode 0x5000, little-endian; protocol version 14 big-endian): sequence
  (0: not used), physical port, the 15-bit port address (Net << 8 | SubUni) and 2..512 slots.
  ArtSync (0x5200) releases buffered ArtDmx. Other OpCodes (ArtPoll ...) are valid and unused.

:func:`parse_e131` and :func:`parse_artnet` return a packet, ``None`` for a valid packet of a
kind we do not use, or raise :class:`DmxDecodeError`; nothing else leaves them (fuzzed).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "ARTNET_PORT",
    "E131_PORT",
    "DmxData",
    "DmxDecodeError",
    "DmxSync",
    "e131_multicast_group",
    "parse_artnet",
    "parse_e131",
]

E131_PORT = 5568
ARTNET_PORT = 6454
_ACN_ID = b"ASC-E1.17\0\0\0"
_ROOT_DATA, _ROOT_EXTENDED = 0x00000004, 0x00000008
_FRAMING_DATA, _FRAMING_SYNC = 0x00000002, 0x00000001
_OPT_PREVIEW, _OPT_TERMINATED = 0x80, 0x40
_ARTNET_ID = b"Art-Net\0"
_OP_DMX, _OP_SYNC = 0x5000, 0x5200
MAX_SLOTS = 512


class DmxDecodeError(ValueError):
    """The bytes are not a well-formed E1.31 or Art-Net packet."""


@dataclass(frozen=True)
class DmxData:
    """One universe's slots from one source. ``source``: the E1.31 CID (hex) or the Art-Net
    sender's host; ``sequence`` None: the sender does not number its packets (Art-Net 0)."""

    universe: int
    slots: bytes  # slot 1 is slots[0]
    source: str
    priority: int = 100
    sequence: int | None = None
    sync_address: int = 0  # E1.31: the universe whose sync packets release this data; 0: none
    terminated: bool = False  # E1.31 stream terminated: the source leaves now
    name: str = ""  # E1.31 source name


@dataclass(frozen=True)
class DmxSync:
    """A universe sync (E1.31 sync packet, sync address) or an ArtSync (address 0)."""

    source: str
    sync_address: int
    sequence: int | None = None


def e131_multicast_group(universe: int) -> str:
    """The E1.31 multicast group of ``universe``: 239.255.<hi>.<lo>."""
    return f"239.255.{universe >> 8 & 0xFF}.{universe & 0xFF}"


def _u16(d: bytes, i: int) -> int:
    return d[i] << 8 | d[i + 1]


def _u32(d: bytes, i: int) -> int:
    return int.from_bytes(d[i : i + 4], "big")


def _pdu_length(d: bytes, i: int, end: int, what: str) -> None:
    """A PDU's flags (0x7) and length field at ``i`` must cover the packet from ``i`` to ``end``."""
    flags, length = d[i] >> 4, _u16(d, i) & 0x0FFF
    if flags != 0x7 or length != end - i:
        raise DmxDecodeError(f"E1.31 {what} layer: flags/length {_u16(d, i):#06x} for {end - i}")


def parse_e131(data: bytes) -> DmxData | DmxSync | None:
    """An E1.31 data or sync packet; ``None`` for another valid packet (discovery, preview
    data, a start code other than 0); :class:`DmxDecodeError` for anything malformed."""
    d = bytes(data)
    n = len(d)
    if n < 49:
        raise DmxDecodeError(f"E1.31: {n} bytes, shorter than any packet")
    if _u16(d, 0) != 0x0010 or _u16(d, 2) != 0 or d[4:16] != _ACN_ID:
        raise DmxDecodeError("E1.31: not an ACN root layer (preamble, 'ASC-E1.17')")
    _pdu_length(d, 16, n, "root")
    root, cid = _u32(d, 18), d[22:38].hex()
    _pdu_length(d, 38, n, "framing")
    framing = _u32(d, 40)
    if root == _ROOT_EXTENDED:
        if framing != _FRAMING_SYNC:
            return None  # universe discovery: valid, unused
        if n != 49:
            raise DmxDecodeError(f"E1.31 sync: {n} bytes, not 49")
        sync = _u16(d, 45)
        if not 1 <= sync <= 63999:
            raise DmxDecodeError(f"E1.31 sync: sync address {sync} outside 1..63999")
        return DmxSync(cid, sync, d[44])
    if root != _ROOT_DATA:
        raise DmxDecodeError(f"E1.31: root vector {root:#x}")
    if framing != _FRAMING_DATA:
        raise DmxDecodeError(f"E1.31: framing vector {framing:#x}")
    if n < 126:
        raise DmxDecodeError(f"E1.31 data: {n} bytes, shorter than 126")
    _pdu_length(d, 115, n, "DMP")
    if d[117] != 0x02 or d[118] != 0xA1 or _u16(d, 119) != 0 or _u16(d, 121) != 1:
        raise DmxDecodeError("E1.31 DMP layer: vector, address type or addressing")
    count = _u16(d, 123)
    if count != n - 125 or count > MAX_SLOTS + 1:
        raise DmxDecodeError(f"E1.31 DMP layer: {count} values for {n - 125} bytes")
    priority, universe, options = d[108], _u16(d, 113), d[112]
    if priority > 200:
        raise DmxDecodeError(f"E1.31: priority {priority} outside 0..200")
    if not 1 <= universe <= 63999:
        raise DmxDecodeError(f"E1.31: universe {universe} outside 1..63999")
    if options & _OPT_PREVIEW or d[125] != 0:
        return None  # preview data, or not DMX levels (start code != 0): not for a figure
    name = d[44:108].split(b"\0", 1)[0].decode("utf-8", "replace")
    return DmxData(
        universe, d[126:], cid, priority, d[111], _u16(d, 109),
        terminated=bool(options & _OPT_TERMINATED), name=name,
    )  # fmt: skip


def parse_artnet(data: bytes, source: str) -> DmxData | DmxSync | None:
    """An ArtDmx or ArtSync packet from host ``source``; ``None`` for another valid Art-Net
    packet (ArtPoll ...); :class:`DmxDecodeError` for anything malformed."""
    d = bytes(data)
    n = len(d)
    if n < 12 or d[:8] != _ARTNET_ID:
        raise DmxDecodeError("Art-Net: no 'Art-Net' header")
    op = d[8] | d[9] << 8
    if op not in (_OP_DMX, _OP_SYNC):
        return None
    if _u16(d, 10) < 14:
        raise DmxDecodeError(f"Art-Net: protocol version {_u16(d, 10)} < 14")
    if op == _OP_SYNC:
        if n < 14:
            raise DmxDecodeError(f"ArtSync: {n} bytes, not 14")
        return DmxSync(source, 0)
    if n < 20:
        raise DmxDecodeError(f"ArtDmx: {n} bytes, shorter than 20")
    length = _u16(d, 16)
    if not 2 <= length <= MAX_SLOTS or length != n - 18:
        raise DmxDecodeError(f"ArtDmx: length {length} for {n - 18} bytes of data")
    if d[15] & 0x80:
        raise DmxDecodeError(f"ArtDmx: Net {d[15]} outside 0..127")
    seq = d[12]
    return DmxData(d[15] << 8 | d[14], d[18:], source, sequence=seq or None)
