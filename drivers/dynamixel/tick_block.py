"""The X series' tick block: health in the tick's own Fast Sync Read, through indirect addresses.

At start-up each servo's Indirect Address 1..7 is pointed at Present Position, Torque Enable,
Bus Watchdog and Status Return Level (:data:`~drivers.protocol2.control_table.TICK_BLOCK`),
so one Fast Sync Read of Indirect Data 1..7 returns, per servo, its position and the state
that says whether it still follows its goals; every tick, with no transaction of its own.

* :func:`restore` reads one servo's Indirect Addresses back and, where they are not the
  block's (a servo fresh from power-up or reboot has them at their defaults), writes them
  and reads them back again.
* :func:`receive_block_reply` takes the Fast Sync Read reply of 7-byte blocks under the
  same rules as :func:`~drivers.dynamixel.fast_reply.parse_blocks` (a block is a reading
  only while every earlier one was, with the ID asked at its place and its running CRC),
  and keeps each servo's state bytes, packed by :func:`pack`.
* A block whose Status Return Level byte is not 2 is not a reading: the servo's Indirect
  Addresses are at their defaults (a brownout or reboot), so its "position" would be 0.

Runs every tick on the bus's thread; the start-up and recovery steps over a
:class:`~drivers.dynamixel.link.Link`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, MutableSequence, Sequence
from typing import TYPE_CHECKING

from drivers.dynamixel.fast_reply import ALERT, ERROR, GOOD
from drivers.dynamixel.tick_packets import CORRUPT, OK, SdkPort, crc_ok, receive_frame
from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK
from drivers.protocol2 import control_table as ct
from drivers.protocol2.crc import CRC_TABLE
from drivers.protocol2.crc import big_endian_word_table as word_table

if TYPE_CHECKING:
    from drivers.dynamixel.link import Link

SIZE = ct.TICK_BLOCK_SIZE
#: the Indirect Addresses as one write (2 bytes each)
TARGETS = ct.tick_block_targets()
#: a block on the wire: ERR, ID, the data, CRC (2)
BLOCK = SIZE + 4
#: the marker byte's value while the block is set
MARKER = ct.STATUS_RETURN_ALL
_ERR_NUMBER, _ALERT_BIT = ct.ERROR_NUMBER_MASK, ct.ALERT_BIT
#: a block as CRC input (four big-endian words, a byte) with its CRC as a word, and as
#: fields (ERR, ID, position, Torque Enable, Bus Watchdog, Status Return Level, CRC)
_WORDS = struct.Struct(">4HBH")
_FIELDS = struct.Struct("<BBiBBBH")
_HEAD = struct.Struct(">4H")  # the reply's first 8 bytes: the CRC's start


def pack(torque: int, watchdog: int, marker: int) -> int:
    """A servo's state bytes as one int (one comparison a servo a tick)."""
    return torque | (watchdog & 0xFF) << 8 | marker << 16


def unpack(state: int) -> tuple[int, int, int]:
    """(Torque Enable, Bus Watchdog (signed), Status Return Level) of a packed state."""
    wd = state >> 8 & 0xFF
    return state & 0xFF, wd - 256 if wd > 127 else wd, state >> 16


def expected(torque_on: bool, watchdog_units: int | None) -> int:
    """The packed state of a servo that follows its goals as the show set it."""
    return pack(int(torque_on), watchdog_units or 0, MARKER)


def block_addr(models: Sequence[str]) -> int | None:
    """Indirect Data 1's address on every one of ``models``, or None when they differ (an
    X330 among X430/X540: one Sync Read reads one address on every servo)."""
    addrs = {ct.indirect_data_1(m) for m in models}
    return addrs.pop() if len(addrs) == 1 else None


def restore(link: Link, servo_id: int) -> bool:
    """Make servo ``servo_id``'s Indirect Address 1..7 the block's: read them back and, if
    they differ, write them and read them back again. Returns whether they were written;
    raises :class:`ValueError` when the write is not confirmed, a
    :class:`~drivers.dynamixel.errors.DynamixelError` when the servo does not answer."""
    start = ct.INDIRECT_ADDRESS_1.addr
    if link.read(servo_id, start, len(TARGETS)) == TARGETS:
        return False
    link.write(servo_id, start, TARGETS)
    got = link.read(servo_id, start, len(TARGETS))
    if got != TARGETS:
        raise ValueError(
            f"servo {servo_id}: Indirect Address 1-{SIZE} read back {got.hex()} after writing "
            f"{TARGETS.hex()}"
        )
    return True


def parse_block_reply(
    packet: bytes | bytearray,
    want: Sequence[int],
    order: Sequence[int],
    pos: MutableSequence[float],
    status: MutableSequence[int],
    errors: MutableSequence[int],
    state: MutableSequence[int],
) -> int:
    """Blocks ``ERR ID data(7) CRC(2)`` from offset 8 under
    :func:`~drivers.dynamixel.fast_reply.parse_blocks`' rules; also each kept servo's
    packed state (:func:`pack`). A block whose marker is not 2 keeps its state and ERR but
    is no reading (its servo stays STALE). Returns how many blocks were kept. Runs every
    tick: each block is two struct unpacks and five CRC steps (four two-byte words and one
    byte; the words need no alignment)."""
    end = len(packet)
    if end < 8 + BLOCK or packet[0:5] != b"\xff\xff\xfd\x00\xfe":
        return 0
    blocks = min((end - 8) // BLOCK, len(want))
    body = packet[8 : 8 + BLOCK * blocks]
    t, tb = word_table(), CRC_TABLE
    h0, h1, h2, h3 = _HEAD.unpack_from(packet)
    crc = t[t[t[t[h0] ^ h1] ^ h2] ^ h3]
    kept = 0
    # a short reply has fewer blocks than servos (and no keyword argument on the tick)
    each = zip(want, order, _WORDS.iter_unpack(body), _FIELDS.iter_unpack(body))  # noqa: B905
    for sid, k, (w0, w1, w2, w3, b8, wc), (err, bid, v, torque, wd, marker, c) in each:
        if bid != sid:
            break
        crc = t[t[t[t[crc ^ w0] ^ w1] ^ w2] ^ w3]
        crc = ((crc << 8) ^ tb[((crc >> 8) ^ b8) & 0xFF]) & 0xFFFF
        if crc != c:
            break
        crc = t[crc ^ wc]  # the next servo's CRC runs on over this one's
        kept += 1
        errors[k] = err
        if err & _ERR_NUMBER:
            status[k] = ALERT if err & _ALERT_BIT else ERROR
            continue
        state[k] = torque | wd << 8 | marker << 16  # pack()
        if marker == MARKER:
            pos[k] = (v - CENTER_TICK) * RAD_PER_TICK
            status[k] = ALERT if err & _ALERT_BIT else GOOD
    return kept


def receive_block_reply(
    port: SdkPort,
    want: Sequence[int],
    order: Sequence[int],
    pos: MutableSequence[float],
    status: MutableSequence[int],
    errors: MutableSequence[int],
    state: MutableSequence[int],
    on_corrupt: Callable[[bytes], object],
) -> None:
    """:func:`~drivers.dynamixel.tick_packets.receive_fast_reply` for the tick block."""
    packet, rx, length = receive_frame(port)
    if rx == OK or (rx == CORRUPT and packet):
        n = len(want)
        kept = parse_block_reply(packet, want, order, pos, status, errors, state)
        whole = kept == n and len(packet) == length == 8 + BLOCK * n
        if rx == OK and not whole and not crc_ok(packet, length):
            rx = CORRUPT
        if rx == CORRUPT:
            on_corrupt(bytes(packet))
