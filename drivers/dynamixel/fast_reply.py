"""A Fast Sync Read reply, parsed by hand: which of its blocks are this tick's readings.

The SDK's Fast Sync Read checks one CRC for the whole packet and reports one result, so
:class:`~drivers.dynamixel.bus.DynamixelBus` takes the packet with ``rxPacket`` and hands
it to :func:`parse_fast_reply`, which keeps each servo's block only on its own merits (see
there). Pure: bytes in, a :class:`~drivers.servo_bus.PresentReading` filled in place; no
SDK, no I/O. Runs every tick.
"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK, decode_position
from drivers.protocol2 import control_table as ct
from drivers.protocol2.crc import CRC_TABLE
from drivers.servo_bus import PresentReading, ReadStatus

#: :class:`~drivers.servo_bus.ReadStatus` as plain ints, for the per-tick loops.
STALE, ERROR, ALERT, GOOD = (
    int(s) for s in (ReadStatus.STALE, ReadStatus.ERROR, ReadStatus.ALERT, ReadStatus.OK)
)


def parse_fast_reply(
    packet: list[int], want: Sequence[int], order: Sequence[int], out: PresentReading
) -> None:
    """Blocks ``ERR ID pos(4) CRC(2)`` from offset 8, one per servo in request order.

    ``want`` are the IDs the Sync Read asked for, in its order; ``order[p]`` is the index
    in ``out`` of the servo asked at position ``p``. ``packet`` is what arrived: a reply
    whose last CRC the SDK found right, or what arrived of a corrupt or short one (any
    length, even under 8 bytes). Either way a block is a reading only if

    * every block before it was one (prefix rule: a bad block costs the servos after
      it this tick, as a silent one does; what follows a bad block may be another
      transaction's reply spliced in),
    * it carries the ID this Sync Read asked for at its position (``want``: a late
      reply to an earlier request has another order after a failed read),
    * its CRC is the running CRC of the packet up to its data. Checked even when the
      SDK verified the packet: after two servos collide on one block, the servos
      after them compute their CRCs over what they heard, so the last CRC can hold
      over a garbled block.

    Fills ``out``'s position, status and error of each servo whose block is a reading;
    leaves the others as they are (the caller has marked them STALE).
    """
    end = len(packet)
    if (
        end < 16
        or packet[0] != 0xFF
        or packet[1] != 0xFF
        or packet[2] != 0xFD
        or packet[3] != 0x00
        or packet[4] != 0xFE
    ):
        return
    pos, status, errors = out.positions, out.status, out.errors
    table = CRC_TABLE
    running = 0
    for b in packet[0:8]:
        running = ((running << 8) ^ table[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
    for p, sid in enumerate(want):
        o = 8 + 8 * p
        if o + 8 > end or packet[o + 1] != sid:
            return
        for b in packet[o : o + 6]:
            running = ((running << 8) ^ table[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
        lo, hi = packet[o + 6], packet[o + 7]
        if running != lo | hi << 8:
            return
        for b in (lo, hi):  # the next servo's CRC runs on over this one's
            running = ((running << 8) ^ table[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
        k = order[p]
        err = packet[o]
        errors[k] = err
        if err & ct.ERROR_NUMBER_MASK:
            status[k] = ALERT if err & ct.ALERT_BIT else ERROR
            continue
        v = packet[o + 2] | packet[o + 3] << 8 | packet[o + 4] << 16 | packet[o + 5] << 24
        pos[k] = (decode_position(v) - CENTER_TICK) * RAD_PER_TICK
        status[k] = ALERT if err & ct.ALERT_BIT else GOOD
