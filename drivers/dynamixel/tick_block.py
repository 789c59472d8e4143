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

from collections.abc import Callable, MutableSequence, Sequence
from typing import TYPE_CHECKING

from drivers.dynamixel.fast_reply import ALERT, ERROR, GOOD, crc16_span
from drivers.dynamixel.tick_packets import CORRUPT, OK, SdkPort, crc_ok, receive_frame
from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK
from drivers.protocol2 import control_table as ct

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
#: the state bytes after the position: Torque Enable, Bus Watchdog, Status Return Level
_TORQUE, _WATCHDOG, _MARKER = 4, 5, 6


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
    is no reading (its servo stays STALE). Returns how many blocks were kept."""
    end = len(packet)
    if end < 8 + BLOCK or packet[0:5] != b"\xff\xff\xfd\x00\xfe":
        return 0
    crc = crc16_span(packet, 0, 8)
    kept = 0
    at = 8
    for sid, k in zip(want, order, strict=False):
        if at + BLOCK > end or packet[at + 1] != sid:
            break
        crc = crc16_span(packet, at, at + 2 + SIZE, crc)
        if crc != packet[at + 2 + SIZE] | packet[at + 3 + SIZE] << 8:
            break
        crc = crc16_span(packet, at + 2 + SIZE, at + BLOCK, crc)
        kept += 1
        err = packet[at]
        errors[k] = err
        if err & _ERR_NUMBER:
            status[k] = ALERT if err & _ALERT_BIT else ERROR
        else:
            d = at + 2
            state[k] = pack(packet[d + _TORQUE], packet[d + _WATCHDOG], packet[d + _MARKER])
            if packet[d + _MARKER] == MARKER:
                v = int.from_bytes(packet[d : d + 4], "little", signed=True)
                pos[k] = (v - CENTER_TICK) * RAD_PER_TICK
                status[k] = ALERT if err & _ALERT_BIT else GOOD
        at += BLOCK
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
