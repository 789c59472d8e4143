"""The tick's packets by hand: byte for byte, call for call what dynamixel-sdk does.

Per tick :class:`~drivers.dynamixel.bus.DynamixelBus` sends one Sync Write of Goal Position
and one (Fast) Sync Read request and takes one Fast Sync Read reply. Through the SDK's
``PacketHandler`` each packet is a fresh list, a byte-stuffing pass over a 1 KiB scratch
list, and ``updateCRC``, which builds its 256-entry table anew on every call: most of a
tick's host time. Here the same bytes come from:

* :class:`GoalFrame`: a Sync Write built once for the bus's IDs; per tick only the goal
  bytes and the CRC are rewritten. A packet in which ``FF FF FD`` follows the header (a
  goal of exactly -131073 ticks, Extended Position mode only) is left to the SDK, whatever
  it makes of it (:meth:`GoalFrame.packet` returns None; :func:`send_goals`);
* :func:`sync_read_request`: the (Fast) Sync Read instruction, built once per read order;
* :func:`transmit`: ``PacketHandler.txPacket``'s steps on the port (busy check, ``clearPort``,
  ``writePort``, the written length), so a busy or vanished port fails the same way;
* :func:`receive_frame` (:func:`receive_fast` with its CRC check):
  ``PacketHandler.rxPacket(port, True)``'s loop, the same calls in the same order
  (``readPort`` asked for the same byte counts, ``isPacketTimeout`` at the same points),
  so the port's waiting, timeouts and host-stall accounting apply unchanged; the packet
  is ``bytes`` instead of a list of ints.

The tick's transactions on top: :func:`send_goals`, :func:`receive_fast_reply` (the reply
parsed, its CRC checked only where the blocks' have not) and :func:`receive_plain_replies`
(a plain Sync Read's chain, through the SDK's ``rxPacket``). CRCs go two bytes a step
through :func:`~drivers.dynamixel.fast_reply.crc16_span` (the CRC of
:func:`~drivers.protocol2.crc.crc16`, a compact table).

``tests/drivers/test_tick_packets.py`` holds these against the SDK's own, on random goals,
ID sets and reply streams.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, MutableSequence, Sequence
from collections.abc import Set as AbstractSet
from typing import Protocol

import dynamixel_sdk as sdk
import numpy as np
from numpy.typing import NDArray

from drivers.dynamixel.fast_reply import (
    ALERT,
    ERROR,
    GOOD,
    crc16_span,
    parse_blocks,
)
from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK, TICKS_PER_RAD, decode_position
from drivers.protocol2 import control_table as ct
from drivers.protocol2.crc import CRC_TABLE
from drivers.protocol2.crc import big_endian_word_table as word_table

#: the SDK's packet limits (``protocol2_packet_handler.TXPACKET_MAX_LEN``/``RXPACKET_MAX_LEN``)
TX_MAX = 1024
RX_MAX = 1024
_HEADER = b"\xff\xff\xfd\x00"
_STUFF = b"\xff\xff\xfd"
_BROADCAST: int = sdk.BROADCAST_ID
GOAL_ADDR = ct.GOAL_POSITION.addr
_STATUS = 0x55
#: the SDK's results (ints; the SDK has no types)
OK: int = sdk.COMM_SUCCESS
PORT_BUSY: int = sdk.COMM_PORT_BUSY
TX_FAIL: int = sdk.COMM_TX_FAIL
TIMEOUT: int = sdk.COMM_RX_TIMEOUT
CORRUPT: int = sdk.COMM_RX_CORRUPT


class SdkPort(Protocol):
    """What a transaction here uses of a port: the SDK's ``PortHandler`` calls (our
    :class:`~drivers.dynamixel.port.PortHandler`, the SDK's own, a test's stand-in)."""

    is_using: bool

    def clearPort(self) -> None: ...
    def writePort(self, packet: bytes | bytearray) -> int: ...
    def readPort(self, length: int) -> bytes: ...
    def isPacketTimeout(self) -> bool: ...
    def setPacketTimeout(self, packet_length: int) -> None: ...


def _instruction(inst: int, params: bytes) -> bytearray:
    """A broadcast instruction packet with room for its CRC (not filled in)."""
    length = len(params) + 3  # INST params CRC(2)
    out = bytearray(_HEADER)
    out += bytes((_BROADCAST, length & 0xFF, length >> 8, inst))
    out += params
    out += b"\x00\x00"
    return out


def _finish(packet: bytearray) -> bytes:
    crc = crc16_span(packet, 0, len(packet) - 2)
    packet[-2], packet[-1] = crc & 0xFF, crc >> 8
    return bytes(packet)


def _stuffed(packet: bytes | bytearray, end: int) -> bool:
    """Whether the SDK's ``addStuffing`` would change this packet: ``FF FF FD`` ending at
    the instruction byte or later, before ``end`` (the CRC)."""
    return _STUFF in packet[5:end]  # (`in`, not find(): no argument parsing on the tick)


class GoalFrame:
    """A Sync Write of ``size``-byte values at ``addr`` for ``ids``, in that order."""

    def __init__(self, ids: Sequence[int], addr: int, size: int = 4) -> None:
        if size != 4:
            raise ValueError("GoalFrame writes 4-byte values")
        n = len(ids)
        params = bytes((addr & 0xFF, addr >> 8, size, 0)) + bytes(5 * n)
        self._buf = _instruction(sdk.INST_SYNC_WRITE, params)
        self.ids = tuple(ids)
        self.size = len(self._buf)
        #: False when the SDK would refuse the packet as too long (``COMM_TX_ERROR``)
        self.fits = self.size <= TX_MAX
        self._args: list[int] = [0] * (2 * n)
        self._args[0::2] = self.ids
        self._pack = struct.Struct("<" + "Bi" * n).pack_into
        self._data = 12  # ID and goal bytes start here, after header, ID, LEN, INST, addr, size
        self._end = self._data + 5 * n  # the CRC
        self._head_crc = crc16_span(self._buf, 0, self._data)
        # the CRC over ID and goal bytes, two a step (as crc16_span, its parts bound once)
        self._words = struct.Struct(f">{5 * n // 2}H").unpack_from
        self._table, self._bytes = word_table(), CRC_TABLE

    def params(self, ticks: Sequence[int]) -> list[int]:
        """The SDK's ``param`` list for ``syncWriteTxOnly``: ID and 4 goal bytes each."""
        out: list[int] = []
        for sid, t in zip(self.ids, ticks, strict=True):
            out.append(sid)
            out += (t & 0xFFFFFFFF).to_bytes(4, "little")
        return out

    def packet(self, ticks: Sequence[int]) -> bytearray | None:
        """The packet for these goal ticks (signed 32-bit each), or None if the SDK would
        have to stuff it (then send ``params(ticks)`` through the SDK). The frame's own
        buffer: valid until the next call."""
        args = self._args
        args[1::2] = ticks
        buf, data, end = self._buf, self._data, self._end
        self._pack(buf, data, *args)
        if _STUFF in buf[5:end]:  # what the SDK would stuff (see _stuffed)
            return None
        crc, t = self._head_crc, self._table
        for w in self._words(buf, data):
            crc = t[crc ^ w]
        if (end - data) & 1:  # an odd number of servos: the last goal byte alone
            crc = ((crc << 8) ^ self._bytes[((crc >> 8) ^ buf[end - 1]) & 0xFF]) & 0xFFFF
        buf[end] = crc & 0xFF
        buf[end + 1] = crc >> 8
        return buf


def sync_read_request(addr: int, size: int, ids: Sequence[int], fast: bool) -> bytes | None:
    """The (Fast) Sync Read instruction ``syncReadTx`` sends for ``ids`` in this order;
    None if the SDK would stuff it or refuse it as too long."""
    inst = sdk.INST_FAST_SYNC_READ if fast else sdk.INST_SYNC_READ
    packet = _instruction(inst, bytes((addr & 0xFF, addr >> 8, size & 0xFF, size >> 8, *ids)))
    if len(packet) > TX_MAX or _stuffed(packet, len(packet) - 2):
        return None
    return _finish(packet)


def transmit(port: SdkPort, packet: bytes | bytearray) -> int:
    """``PacketHandler.txPacket`` for a finished packet: refuse a busy port, take it,
    clear its input, write. Leaves the port taken on success, as the SDK does (a broadcast
    write's caller frees it; a read's ``receive`` does)."""
    if port.is_using:
        return PORT_BUSY
    port.is_using = True
    port.clearPort()
    if port.writePort(packet) != len(packet):
        port.is_using = False
        return TX_FAIL
    return OK


def _header_at(buf: bytes, n: int) -> int:
    """Where ``rxPacket`` finds a header in the first ``n`` bytes: the first ``FF FF FD``
    not followed by ``FD``; when there is none, its loop's last index, ``n - 4``."""
    i = buf.find(_STUFF, 0, n)
    while 0 <= i <= n - 4:
        if buf[i + 3] != 0xFD:
            return i
        i = buf.find(_STUFF, i + 1, n)
    return n - 4


def receive_frame(port: SdkPort, max_id: int = _BROADCAST) -> tuple[bytes, int, int]:
    """``PacketHandler.rxPacket(port, True)`` up to its CRC check: ``(packet, result,
    length)`` with result TIMEOUT or CORRUPT as the SDK's, or OK for a framed packet of
    ``length`` bytes whose CRC is still to be checked (:func:`crc_ok`); the port freed.
    The same ``readPort``/``isPacketTimeout`` calls in the same order. ``max_id``: the
    highest ID a status packet may carry (``rxPacket(port, False)`` allows MAX_ID only)."""
    read, timed_out = port.readPort, port.isPacketTimeout
    rx = b""
    result = TX_FAIL
    rx_length = 0
    wait_length = 11  # HEADER(4) ID LEN(2) INST ERR CRC(2): the least a status packet is
    while True:
        rx += read(wait_length - rx_length)
        rx_length = len(rx)
        if rx_length >= wait_length:
            idx = 0 if rx[:3] == _STUFF and rx[3] != 0xFD else _header_at(rx, rx_length)
            if idx == 0:
                length = rx[5] | rx[6] << 8
                if rx[3] != 0x00 or rx[4] > max_id or length > RX_MAX or rx[7] != _STATUS:
                    rx = rx[1:]
                    rx_length -= 1
                    continue
                if wait_length != length + 7:
                    wait_length = length + 7
                    continue
                if rx_length < wait_length:
                    if timed_out():
                        result = TIMEOUT if rx_length == 0 else CORRUPT
                        break
                    continue
                result = OK
                break
            rx = rx[idx:]
            rx_length -= idx
        elif timed_out():
            result = TIMEOUT if rx_length == 0 else CORRUPT
            break
    port.is_using = False
    return rx, result, wait_length


def crc_ok(packet: bytes, length: int) -> bool:
    """The SDK's check of a framed packet: its last two bytes of ``length`` are the CRC of
    the bytes before them."""
    return crc16_span(packet, 0, length - 2) == packet[length - 2] | packet[length - 1] << 8


def receive_fast(port: SdkPort) -> tuple[bytes, int]:
    """``PacketHandler.rxPacket(port, True)``: the Fast Sync Read reply and its result
    (OK, TIMEOUT or CORRUPT), the port freed; what it returns compares equal to the SDK's
    list. (The bus takes :func:`receive_frame` and checks the CRC only where the blocks'
    own CRCs have not already checked it.)"""
    rx, result, length = receive_frame(port)
    if result == OK and not crc_ok(rx, length):
        result = CORRUPT
    return rx, result


def read_request(servo_id: int, addr: int, size: int) -> bytes | None:
    """The Read instruction ``PacketHandler.readTxRx`` sends; None if the SDK would stuff
    it (then it goes through the SDK)."""
    packet = _instruction(sdk.INST_READ, bytes((addr & 0xFF, addr >> 8, size & 0xFF, size >> 8)))
    packet[4] = servo_id
    return None if _stuffed(packet, len(packet) - 2) else _finish(packet)


def read_transaction(
    port: SdkPort, request: bytes, servo_id: int, size: int
) -> tuple[bytes, int, int]:
    """``PacketHandler.txRxPacket(port, <Read of size bytes>)`` for a finished ``request``
    (:func:`read_request`): ``(status packet, result, error)`` as the SDK's, the same port
    calls in the same order. Status packets from other IDs are skipped, as the SDK skips
    them; a packet the SDK would un-stuff is un-stuffed."""
    result = transmit(port, request)
    if result != OK:
        return b"", result, 0
    port.setPacketTimeout(size + 11)
    while True:  # rxPacket(port, False): framed, CRC checked, un-stuffed
        rx, result, length = receive_frame(port, sdk.MAX_ID)
        if result == OK:
            if not crc_ok(rx, length):
                result = CORRUPT
            elif _STUFF + b"\xfd" in rx:
                rx = bytes(sdk.PacketHandler(2.0).removeStuffing(list(rx)))
        if result != OK or rx[4] == servo_id:
            break
    return rx, result, (rx[8] if result == OK else 0)


# ----------------------------------------------------------------------- the transactions
def finite_goals(goals: object, n: int) -> list[float] | None:
    """``goals`` as n finite Python numbers when they are a list or an ``(n,)`` float64
    array of them (the tick's case), else None (then ServoBus checks them, and raises)."""
    if type(goals) is list:
        values = goals
    elif type(goals) is np.ndarray and goals.dtype == np.float64 and goals.shape == (n,):
        values = goals.tolist()
    else:
        return None
    if len(values) != n:
        return None
    try:
        total = sum(values)
    except TypeError:  # not numbers
        return None
    return values if total - total == 0.0 else None  # a NaN or inf makes the sum one


def send_goals(
    port: SdkPort, ph: sdk.Protocol2PacketHandler, frame: GoalFrame, ticks: Sequence[int]
) -> int:
    """``PacketHandler.syncWriteTxOnly`` of these goal ticks: :func:`transmit` of the
    frame's packet, the port freed at once (a broadcast: no status packet). A packet the
    SDK would stuff, or refuse as too long, the SDK builds and sends itself."""
    packet = frame.packet(ticks) if frame.fits else None
    if packet is None:
        sent: int = ph.syncWriteTxOnly(port, GOAL_ADDR, 4, frame.params(ticks), 5 * len(ticks))
        return sent
    result = transmit(port, packet)
    if result == OK:
        port.is_using = False
    return result


def goal_range_error(
    ids: Sequence[int],
    goals: Sequence[float] | NDArray[np.float64],
    lo: Sequence[float] | NDArray[np.float64],
    hi: Sequence[float] | NDArray[np.float64],
) -> ValueError:
    """The error for goals outside what the servos accept: each one named, rad and tick."""
    t = np.rint(np.asarray(goals, dtype=np.float64) * TICKS_PER_RAD) + CENTER_TICK
    bad = [
        f"servo {sid}: {g:+.4f} rad = tick {int(x)} outside [{int(a)}, {int(b)}]"
        for sid, g, x, a, b in zip(ids, goals, t, lo, hi, strict=True)
        if not a <= x <= b
    ]
    return ValueError("goal out of range, nothing sent: " + "; ".join(bad))


def receive_fast_reply(
    port: SdkPort,
    want: Sequence[int],
    order: Sequence[int],
    pos: MutableSequence[float],
    status: MutableSequence[int],
    errors: MutableSequence[int],
    on_corrupt: Callable[[bytes], object],
) -> None:
    """The reply to a Fast Sync Read of ``want`` (IDs in request order; ``order[p]`` the
    index of the servo asked at ``p``): :func:`receive_frame`, its blocks parsed into
    ``pos``/``status``/``errors`` (:func:`~drivers.dynamixel.fast_reply.parse_blocks`),
    whole or corrupt; ``on_corrupt(bytes)`` is told of a packet the SDK calls corrupt.
    The packet's own CRC is checked only where the blocks' CRCs have not: when every block
    of a packet of the asked length was kept, the last one's CRC was the packet's."""
    packet, rx, length = receive_frame(port)
    if rx == OK or (rx == CORRUPT and packet):
        n = len(want)
        kept = parse_blocks(packet, want, order, pos, status, errors)
        whole = kept == n and len(packet) == length == 8 + 8 * n
        if rx == OK and not whole and not crc_ok(packet, length):
            rx = CORRUPT
        if rx == CORRUPT:
            on_corrupt(bytes(packet))


def receive_plain_replies(
    ph: sdk.Protocol2PacketHandler,
    port: SdkPort,
    want: Sequence[int],
    order: Sequence[int],
    pos: MutableSequence[float],
    status: MutableSequence[int],
    errors: MutableSequence[int],
    on_corrupt: Callable[[bytes], object],
    size: int = 4,
    late: AbstractSet[int] = frozenset(),
) -> None:
    """The chain of status packets answering a plain Sync Read of ``size`` bytes from
    Present Position, in the order asked (each servo answers after the one before it),
    through ``ph.rxPacket``. A packet is a reading only if it carries the ID asked at its
    place and ``size`` bytes; one with other data (a late reply to an earlier read that
    asked another length: ``read_order``) is passed over. A packet with an error number has
    no data whatever was asked: from a servo in ``late`` (whose late packet may still come)
    it cannot be told from a late one, so it is no reading (STALE) and takes its place if
    it is that servo's (and that servo's reply, if one follows at once, is read), else is
    passed over. A corrupt one takes its place
    (that servo only loses this tick); a valid one from another ID - a late reply to an
    earlier request, whose chain had another order, a stranger, a second reply - ends the
    read, since what follows it cannot be placed. ``on_corrupt(bytes)`` is told of each
    corrupt packet as it comes."""
    p, n, length = 0, len(want), size + 4  # LEN = INST ERR data CRC(2)
    redo = -1  # a place such an error packet took: its servo's own reply may still follow
    while p < n:
        packet, result = ph.rxPacket(port, False)
        if result == OK:
            err, sid = packet[8], packet[4]
            if (packet[5] | packet[6] << 8) != length:
                if not err & ct.ERROR_NUMBER_MASK:
                    continue  # another request's reply: not this read's, nor its end
                if sid in late:  # an error packet has no data: late or this read's?
                    if sid == want[p]:
                        redo, p = p, p + 1  # its place: no reading (STALE), the rest read
                    continue
            if sid != want[p]:
                if redo < 0 or sid != want[redo]:
                    return
                k = order[redo]  # the error packet was a late one: here is its own reply
            else:
                k = order[p]
                p += 1
            redo = -1
            errors[k] = err
            if err & ct.ERROR_NUMBER_MASK:
                status[k] = ALERT if err & ct.ALERT_BIT else ERROR
            else:
                v = packet[9] | packet[10] << 8 | packet[11] << 16 | packet[12] << 24
                pos[k] = (decode_position(v) - CENTER_TICK) * RAD_PER_TICK
                status[k] = ALERT if err & ct.ALERT_BIT else GOOD
        elif result == TIMEOUT:
            return
        else:  # corrupt: this place's reply is lost; the next may be fine
            on_corrupt(bytes(packet))
            p += 1
