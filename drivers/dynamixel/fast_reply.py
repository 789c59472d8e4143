"""A Fast Sync Read reply, parsed by hand: which of its blocks are this tick's readings.

The SDK's Fast Sync Read checks one CRC for the whole packet and reports one result, so
:class:`~drivers.dynamixel.bus.DynamixelBus` takes the packet with
:func:`~drivers.dynamixel.tick_packets.receive_fast` and hands it to :func:`parse_blocks`
(lists, the tick's path) or :func:`parse_fast_reply` (a
:class:`~drivers.servo_bus.PresentReading`), which keep each servo's block only on its own
merits (see there). Pure: bytes in, readings out; no SDK, no I/O. Runs every tick, so the
per-block CRCs go two bytes per step through the CRC's big-endian word table
(:func:`~drivers.protocol2.crc.big_endian_word_table`) and the blocks are read
with :mod:`struct`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import MutableSequence, Sequence
from functools import cache

from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK
from drivers.protocol2 import control_table as ct
from drivers.protocol2.crc import CRC_TABLE
from drivers.protocol2.crc import big_endian_word_table as word_table
from drivers.servo_bus import PresentReading, ReadStatus

#: :class:`~drivers.servo_bus.ReadStatus` as plain ints, for the per-tick loops.
STALE, ERROR, ALERT, GOOD = (
    int(s) for s in (ReadStatus.STALE, ReadStatus.ERROR, ReadStatus.ALERT, ReadStatus.OK)
)
_ERR_NUMBER = ct.ERROR_NUMBER_MASK
_ALERT = ct.ALERT_BIT
#: a block as CRC input (four big-endian words) and as fields (ERR, ID, position, CRC)
_WORDS = struct.Struct(">4H")
_FIELDS = struct.Struct("<BBiH")


@cache
def _words(n: int) -> struct.Struct:
    return struct.Struct(f">{n}H")


def crc16_span(data: bytes | bytearray, start: int, stop: int, crc: int = 0) -> int:
    """:func:`~drivers.protocol2.crc.crc16` of ``data[start:stop]`` from ``crc``, two bytes
    a step."""
    t = word_table()
    for w in _words((stop - start) >> 1).unpack_from(data, start):
        crc = t[crc ^ w]
    if (stop - start) & 1:
        crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ data[stop - 1]) & 0xFF]) & 0xFFFF
    return crc


def parse_blocks(
    packet: bytes | bytearray,
    want: Sequence[int],
    order: Sequence[int],
    pos: MutableSequence[float],
    status: MutableSequence[int],
    errors: MutableSequence[int],
) -> int:
    """Blocks ``ERR ID pos(4) CRC(2)`` from offset 8, one per servo in request order.

    ``want`` are the IDs the Sync Read asked for, in its order; ``order[p]`` is the index
    in the outputs of the servo asked at position ``p``. ``packet`` is what arrived: a
    reply whose last CRC was found right, or what arrived of a corrupt or short one (any
    length, even under 8 bytes). Either way a block is a reading only if

    * every block before it was one (prefix rule: a bad block costs the servos after
      it this tick, as a silent one does; what follows a bad block may be another
      transaction's reply spliced in),
    * it carries the ID this Sync Read asked for at its position (``want``: a late
      reply to an earlier request has another order after a failed read),
    * its CRC is the running CRC of the packet up to its data. Checked even when the
      whole packet's CRC is right: after two servos collide on one block, the servos
      after them compute their CRCs over what they heard, so the last CRC can hold
      over a garbled block.

    Writes the position (rad, servo frame), status and ERR byte of each servo whose block
    is a reading; leaves the others as they are (the caller has marked them STALE).
    Returns how many blocks were readings.
    """
    end = len(packet)
    if end < 16 or packet[0:5] != b"\xff\xff\xfd\x00\xfe":
        return 0
    blocks = (end - 8) >> 3
    if blocks > len(want):
        blocks = len(want)
    body = packet[8 : 8 + 8 * blocks]
    t = word_table()
    h0, h1, h2, h3 = _WORDS.unpack_from(packet)
    crc = t[t[t[t[h0] ^ h1] ^ h2] ^ h3]
    p = 0
    # a short reply has fewer blocks than servos (and no keyword argument on the tick)
    each = zip(want, order, _WORDS.iter_unpack(body), _FIELDS.iter_unpack(body))  # noqa: B905
    for sid, k, (w0, w1, w2, w3), (err, bid, v, c) in each:
        if bid != sid:
            break
        crc = t[t[t[crc ^ w0] ^ w1] ^ w2]
        if crc != c:
            break
        crc = t[crc ^ w3]  # the next servo's CRC runs on over this one's
        p += 1
        errors[k] = err
        if err & _ERR_NUMBER:
            status[k] = ALERT if err & _ALERT else ERROR
            continue
        pos[k] = (v - CENTER_TICK) * RAD_PER_TICK
        status[k] = ALERT if err & _ALERT else GOOD
    return p


def parse_fast_reply(
    packet: bytes | bytearray | Sequence[int],
    want: Sequence[int],
    order: Sequence[int],
    out: PresentReading,
) -> None:
    """:func:`parse_blocks` into ``out``: the position, status and error of each servo
    whose block is a reading; the others are left as they are."""
    n = len(out.ids)
    pos, status, errors = [math.nan] * n, [-1] * n, [-1] * n
    data = packet if isinstance(packet, bytes | bytearray) else bytes(packet)
    if not parse_blocks(data, want, order, pos, status, errors):
        return
    for k in range(n):
        if status[k] >= 0:
            out.positions[k], out.status[k], out.errors[k] = pos[k], status[k], errors[k]
