"""The tick's hand-built packets against dynamixel-sdk's own: the same bytes on the wire, the
same calls on the port, the same results (drivers.dynamixel.tick_packets, fast_reply)."""

from __future__ import annotations

import math
import random

import dynamixel_sdk as sdk
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dynamixel import units
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.fast_reply import (
    ALERT,
    ERROR,
    GOOD,
    STALE,
    crc16_span,
    parse_blocks,
    parse_fast_reply,
)
from drivers.dynamixel.link import Link
from drivers.dynamixel.port import PortHandler
from drivers.dynamixel.startup import ReadMode
from drivers.dynamixel.tick_packets import (
    CORRUPT,
    OK,
    PORT_BUSY,
    TIMEOUT,
    TX_FAIL,
    GoalFrame,
    read_request,
    read_transaction,
    receive_fast,
    sync_read_request,
    transmit,
)
from drivers.fill import Packed, packer
from drivers.protocol2 import control_table as ct
from drivers.protocol2.crc import CRC_TABLE, crc16
from drivers.servo_bus import PresentReading

GOAL, PRESENT = ct.GOAL_POSITION.addr, ct.PRESENT_POSITION.addr
EXTENDED = ct.EXTENDED_GOAL_LIMIT


class Recorder:
    """A serial stand-in that keeps every written packet (and answers nothing)."""

    def __init__(self) -> None:
        self.written: list[bytes] = []
        self.timeout = 0

    def write(self, data) -> int:
        self.written.append(bytes(data))
        return len(self.written[-1])

    def read(self, n: int) -> bytes:
        return b""

    def reset_input_buffer(self) -> None:
        pass

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


def recording_port(kind: str = "sdk"):
    port = sdk.PortHandler("rec") if kind == "sdk" else PortHandler("rec")
    port.ser, port.is_open, port.baudrate, port.tx_time_per_byte = Recorder(), True, 1e6, 0.01
    return port


def sdk_sync_write(ids, ticks) -> bytes:
    port, ph = recording_port(), sdk.PacketHandler(2.0)
    params = []
    for sid, t in zip(ids, ticks, strict=True):
        params += [sid, *(t & 0xFFFFFFFF).to_bytes(4, "little")]
    assert ph.syncWriteTxOnly(port, GOAL, 4, params, len(params)) == sdk.COMM_SUCCESS
    (packet,) = port.ser.written
    return packet


ids_sets = st.lists(st.integers(0, 252), min_size=1, max_size=24, unique=True)


# ------------------------------------------------------------------ the Sync Write
@settings(max_examples=300)
@given(ids=ids_sets, data=st.data())
def test_goal_frame_is_the_sdks_sync_write(ids, data):
    frame = GoalFrame(ids, GOAL)
    for _ in range(3):  # the same frame, refilled
        ticks = data.draw(
            st.lists(
                st.one_of(st.integers(0, 4095), st.integers(-EXTENDED, EXTENDED)),
                min_size=len(ids),
                max_size=len(ids),
            )
        )
        packet = frame.packet(ticks)
        sdk_packet = sdk_sync_write(ids, ticks)
        if packet is None:  # left to the SDK: only a goal of exactly FF FF FD FF
            assert -131073 in ticks
        else:
            assert bytes(packet) == sdk_packet
        assert frame.params(ticks) == list(sdk_packet[12 : 12 + 5 * len(ids)]) or packet is None


def test_a_goal_the_sdk_would_stuff_goes_through_the_sdk():
    """A goal of -131073 ticks is FF FF FD FF: the frame leaves it to the SDK, whatever the
    SDK makes of it (4.1 drops ``addStuffing``'s longer packet and sends it unstuffed)."""
    ids, ticks = (1, 2), [2048, -131073]
    assert GoalFrame(ids, GOAL).packet(ticks) is None
    port = recording_port("hilsim")
    bus = DynamixelBus(Link(port), ids, ReadMode.FAST, 0)
    bus._lo[:], bus._hi[:] = -EXTENDED, EXTENDED  # Extended Position mode, as check() finds it
    bus._lo_l, bus._hi_l = bus._lo.tolist(), bus._hi.tolist()
    bus.write_goals([0.0, (-131073 - 2048) * units.RAD_PER_TICK])
    assert port.ser.written == [sdk_sync_write(ids, ticks)]


@settings(max_examples=100)
@given(ids=ids_sets, seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(["list", "array"]))
def test_write_goals_puts_the_sdks_bytes_on_the_wire(ids, seed, kind):
    rng = np.random.default_rng(seed)
    port = recording_port("hilsim")
    bus = DynamixelBus(Link(port), ids, ReadMode.FAST, 0)
    goals = rng.uniform(-3.0, 3.0, len(ids))
    goals[rng.random(len(ids)) < 0.2] = rng.integers(-2048, 2048) * units.RAD_PER_TICK  # exact
    bus.write_goals(goals.tolist() if kind == "list" else goals)
    ticks = [int(t) for t in np.rint(goals * units.TICKS_PER_RAD) + units.CENTER_TICK]
    assert port.ser.written == [sdk_sync_write(ids, ticks)]
    assert bus.stats.writes == 1 and not port.is_using


def test_halfway_goals_round_to_even_as_numpy_does():
    ids = (1, 2, 3, 4)
    port = recording_port("hilsim")
    bus = DynamixelBus(Link(port), ids, ReadMode.FAST, 0)
    goals = np.array([0.5, 1.5, -0.5, 2.5]) * units.RAD_PER_TICK
    ticks = np.rint(goals * units.TICKS_PER_RAD) + units.CENTER_TICK
    bus.write_goals(goals)
    assert port.ser.written == [sdk_sync_write(ids, [int(t) for t in ticks])]


@pytest.mark.parametrize(
    ("goals", "error", "match"),
    [
        ([0.0, 0.0], ValueError, "shaped"),
        ([0.0, math.nan, 0.0], ValueError, r"non-finite goal for servo\(s\) \[2\]"),
        ([0.0, 0.0, math.inf], ValueError, "non-finite"),
        ([0.0, 0.0, 3.2], ValueError, r"servo 3: \+3.2000 rad = tick 4134 outside \[0, 4095\]"),
        (["a", 0.0, 0.0], ValueError, "could not convert"),
        # finite, but their sum is not: ServoBus's path; a tick beyond a float (as before)
        ([1e308, 1e308, 0.0], OverflowError, "cannot convert float infinity"),
    ],
)
def test_write_goals_refuses_what_servobus_refuses(goals, error, match):
    port = recording_port("hilsim")
    bus = DynamixelBus(Link(port), (1, 2, 3), ReadMode.FAST, 0)
    for g in (goals, np.array(goals, dtype=object if isinstance(goals[0], str) else float)):
        with pytest.raises(error, match=match):
            bus.write_goals(g)
    assert port.ser.written == [] and bus.stats.writes == 0


# ------------------------------------------------------------------ the Sync Read request
@settings(max_examples=200)
@given(ids=ids_sets, fast=st.booleans())
def test_sync_read_request_is_the_sdks(ids, fast):
    port, ph = recording_port(), sdk.PacketHandler(2.0)
    assert ph.syncReadTx(port, PRESENT, 4, list(ids), len(ids), fast) == sdk.COMM_SUCCESS
    assert sync_read_request(PRESENT, 4, ids, fast) == port.ser.written[0]


def test_transmit_fails_as_the_sdks_txpacket_does():
    packet = sync_read_request(PRESENT, 4, (1, 2), True)
    port = recording_port("hilsim")
    port.is_using = True
    assert transmit(port, packet) == PORT_BUSY and port.is_using and port.ser.written == []
    port.is_using = False
    assert transmit(port, packet) == OK and port.is_using  # the reply's receive frees it
    port.is_using = False
    port.ser.write = lambda data: len(data) - 1  # a short write
    assert transmit(port, packet) == TX_FAIL and not port.is_using


# ------------------------------------------------------------------ the reply
class Scripted:
    """A port whose reads hand out a byte stream in given chunk sizes and whose timeout
    fires at a given poll; it logs every call the receive makes."""

    def __init__(self, stream: bytes, chunks: list[int], timeout_after: int) -> None:
        self.stream, self.chunks, self.timeout_after = stream, list(chunks), timeout_after
        self.calls: list[tuple] = []
        self.is_using = True
        self._polls = 0

    def readPort(self, length):
        take = min(length, self.chunks.pop(0) if self.chunks else length)
        out, self.stream = self.stream[:take], self.stream[take:]
        self.calls.append(("read", length, len(out)))
        return out

    def isPacketTimeout(self):
        self._polls += 1
        self.calls.append(("timeout?", self._polls))
        return self._polls > self.timeout_after


def fast_reply(ids, ticks, errors=None) -> bytes:
    errors = errors or [0] * len(ids)
    length = 1 + 8 * len(ids)
    out = bytearray(b"\xff\xff\xfd\x00\xfe") + bytes((length & 0xFF, length >> 8, 0x55))
    crc = crc16(out)
    for sid, t, err in zip(ids, ticks, errors, strict=True):
        block = bytes((err, sid)) + (t & 0xFFFFFFFF).to_bytes(4, "little")
        out += block
        crc = crc16(block, crc)
        out += bytes((crc & 0xFF, crc >> 8))
        crc = crc16(out[-2:], crc)
    return bytes(out)


def mangle(data: bytes, rng: random.Random) -> bytes:
    """Garbage before, a flipped or dropped byte, a cut, a header look-alike."""
    b = bytearray(data)
    kind = rng.randrange(7)
    if kind == 0 and b:
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif kind == 1:
        b[0:0] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 12)))
    elif kind == 2:
        del b[rng.randrange(len(b) + 1) :]
    elif kind == 3:
        b[0:0] = b"\xff\xff\xfd\xfd" + bytes(rng.randrange(256) for _ in range(rng.randrange(8)))
    elif kind == 4 and len(b) > 6:
        b[5], b[6] = rng.randrange(256), rng.randrange(6)  # another LEN
    elif kind == 5 and len(b) > 7:
        b[rng.choice((3, 4, 7))] = rng.randrange(256)
    return bytes(b)


@settings(max_examples=400)
@given(
    n=st.integers(1, 8),
    seed=st.integers(0, 2**32 - 1),
    mangles=st.integers(0, 3),
    timeout_after=st.integers(0, 6),
)
def test_receive_fast_is_the_sdks_rxpacket_call_for_call(n, seed, mangles, timeout_after):
    rng = random.Random(seed)
    ids = rng.sample(range(253), n)
    data = fast_reply(ids, [rng.randrange(-5000, 9000) for _ in ids])
    for _ in range(mangles):
        data = mangle(data, rng)
    if rng.random() < 0.3:
        data += bytes(rng.randrange(256) for _ in range(rng.randrange(20)))  # what follows
    chunks = [rng.randrange(1, 30) for _ in range(40)]
    ours, theirs = Scripted(data, chunks, timeout_after), Scripted(data, chunks, timeout_after)
    packet, result = receive_fast(ours)
    sdk_packet, sdk_result = sdk.PacketHandler(2.0).rxPacket(theirs, True)
    assert (list(packet), result) == (sdk_packet, sdk_result)
    assert ours.calls == theirs.calls and not ours.is_using and not theirs.is_using


def test_receive_fast_results():
    ids = [3, 1]
    whole = fast_reply(ids, [100, 200])
    assert receive_fast(Scripted(whole, [], 0)) == (whole, OK)
    assert receive_fast(Scripted(b"", [], 0)) == (b"", TIMEOUT)
    assert receive_fast(Scripted(whole[:-3], [], 2))[1] == CORRUPT
    bad = bytearray(whole)
    bad[10] ^= 0x40
    assert receive_fast(Scripted(bytes(bad), [], 0)) == (bytes(bad), CORRUPT)


class ScriptedTx(Scripted):
    """:class:`Scripted` that also takes a transmit: it logs what is written and the
    packet timeout set."""

    def __init__(self, stream: bytes, chunks: list[int], timeout_after: int) -> None:
        super().__init__(stream, chunks, timeout_after)
        self.is_using = False

    def clearPort(self):
        self.calls.append(("clear",))

    def writePort(self, packet):
        self.calls.append(("write", bytes(packet)))
        return len(packet)

    def setPacketTimeout(self, length):
        self.calls.append(("timeout", length))


def status_packet(sid: int, err: int, data: bytes) -> bytes:
    """A status packet as a servo sends it: stuffed where ``FF FF FD`` occurs."""
    body = bytearray((sid, 0, 0, 0x55, err)) + data
    i = body.find(b"\xff\xff\xfd", 3)
    while i >= 0:
        body[i + 3 : i + 3] = b"\xfd"
        i = body.find(b"\xff\xff\xfd", i + 4)
    length = len(body) - 3 + 2
    body[1], body[2] = length & 0xFF, length >> 8
    out = b"\xff\xff\xfd\x00" + bytes(body)
    crc = crc16(out)
    return out + bytes((crc & 0xFF, crc >> 8))


@settings(max_examples=400)
@given(
    sid=st.integers(0, 252),
    addr=st.integers(0, 700),
    size=st.integers(1, 12),
    seed=st.integers(0, 2**32 - 1),
    mangles=st.integers(0, 2),
    timeout_after=st.integers(0, 6),
)
def test_read_transaction_is_the_sdks_txrxpacket_call_for_call(
    sid, addr, size, seed, mangles, timeout_after
):
    rng = random.Random(seed)
    data = bytes(rng.choice((0xFF, 0xFD, rng.randrange(256))) for _ in range(size))
    stream = b""
    if rng.random() < 0.3:  # a late reply from another servo first: skipped
        stream += status_packet(rng.choice([i for i in range(253) if i != sid]), 0, data)
    stream += status_packet(sid, rng.choice((0, 0, 0x80, 0x02)), data)
    for _ in range(mangles):
        stream = mangle(stream, rng)
    chunks = [rng.randrange(1, 30) for _ in range(40)]
    request = read_request(sid, addr, size)
    tx = [0] * 14
    tx[4], tx[5], tx[6], tx[7] = sid, 7, 0, sdk.INST_READ
    tx[8:12] = addr & 0xFF, addr >> 8, size & 0xFF, size >> 8
    ours, theirs = (
        ScriptedTx(stream, chunks, timeout_after),
        ScriptedTx(stream, chunks, timeout_after),
    )
    sdk_rx, sdk_result, sdk_error = sdk.PacketHandler(2.0).txRxPacket(theirs, tx)
    if request is None:  # the SDK would stuff the request: Link leaves it to the SDK
        assert b"\xff\xff\xfd" in theirs.calls[1][1][5:]
        return
    rx, result, error = read_transaction(ours, request, sid, size)
    assert (list(rx), result, error) == (sdk_rx, sdk_result, sdk_error)
    assert ours.calls == theirs.calls and not ours.is_using and not theirs.is_using


# ------------------------------------------------------------------ the CRC and the parser
@settings(max_examples=200)
@given(data=st.binary(max_size=300), start=st.integers(0, 8), crc=st.integers(0, 0xFFFF))
def test_crc16_span_is_crc16(data, start, crc):
    start = min(start, len(data))
    assert crc16_span(data, start, len(data), crc) == crc16(data[start:], crc)


def reference_parse(packet, want, order, out: PresentReading) -> None:
    """parse_fast_reply as it was before the tick was sped up (byte table, per byte)."""
    end = len(packet)
    if end < 16 or list(packet[:5]) != [0xFF, 0xFF, 0xFD, 0x00, 0xFE]:
        return
    running = 0
    for b in packet[0:8]:
        running = ((running << 8) ^ CRC_TABLE[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
    for p, sid in enumerate(want):
        o = 8 + 8 * p
        if o + 8 > end or packet[o + 1] != sid:
            return
        for b in packet[o : o + 6]:
            running = ((running << 8) ^ CRC_TABLE[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
        lo, hi = packet[o + 6], packet[o + 7]
        if running != lo | hi << 8:
            return
        for b in (lo, hi):
            running = ((running << 8) ^ CRC_TABLE[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
        k = order[p]
        err = packet[o]
        out.errors[k] = err
        if err & ct.ERROR_NUMBER_MASK:
            out.status[k] = ALERT if err & ct.ALERT_BIT else ERROR
            continue
        v = packet[o + 2] | packet[o + 3] << 8 | packet[o + 4] << 16 | packet[o + 5] << 24
        out.positions[k] = (units.decode_position(v) - units.CENTER_TICK) * units.RAD_PER_TICK
        out.status[k] = ALERT if err & ct.ALERT_BIT else GOOD


@settings(max_examples=400)
@given(n=st.integers(1, 10), seed=st.integers(0, 2**32 - 1), mangles=st.integers(0, 3))
def test_parse_keeps_exactly_the_blocks_it_kept_before(n, seed, mangles):
    rng = random.Random(seed)
    ids = rng.sample(range(253), n)
    errors = [rng.choice((0, 0, 0, 0x80, 0x04, 0x87)) for _ in ids]
    data = fast_reply(ids, [rng.randrange(-(2**31), 2**31) for _ in ids], errors)
    for _ in range(mangles):
        data = mangle(data, rng)
    want = ids if rng.random() < 0.8 else rng.sample(ids, n)
    order = rng.sample(range(n), n)
    ref, new = PresentReading.empty(range(n)), PresentReading.empty(range(n))
    reference_parse(data, want, order, ref)
    parse_fast_reply(data, want, order, new)
    np.testing.assert_array_equal(new.positions, ref.positions)
    assert new.status.tolist() == ref.status.tolist()
    assert new.errors.tolist() == ref.errors.tolist()
    pos, status, errs = [math.nan] * n, [STALE] * n, [0] * n
    kept = parse_blocks(data, want, order, pos, status, errs)
    assert status == ref.status.tolist() and kept == sum(s != STALE for s in status)


# ------------------------------------------------------------------ packed array reads and writes
@pytest.mark.parametrize("dtype", ["float64", "uint8", "int8"])
def test_packed_reads_and_writes_what_numpy_does(dtype):
    values = [1.5, -0.0, math.nan, 7.0] if dtype == "float64" else [0, 3, 1, 2]
    a, b = np.zeros(4, dtype=dtype), np.zeros(4, dtype=dtype)
    view = Packed(a, 4)
    view.put(*values)
    b[:] = values
    assert a.tobytes() == b.tobytes() and packer(a) is not None
    assert repr(view.tolist()) == repr(b.tolist())
    assert [type(x) for x in view.tolist()] == [type(x) for x in b.tolist()]
    for other in (np.zeros(8, dtype=dtype)[::2], np.zeros(4, dtype=">f8"), np.zeros(5)):
        assert packer(other) is None or other.size != 4
        fallback = Packed(other, 4)  # numpy's ways, and numpy's errors
        if other.size == 4:
            fallback.put(*values)
            expected = np.zeros_like(other)
            expected[:] = values
            assert repr(fallback.tolist()) == repr(expected.tolist())
        else:
            with pytest.raises(ValueError):
                fallback.put(*values)
    assert Packed().of(a) is not None and view.of(a) is view


def test_a_packed_view_copies_and_pickles_as_a_view_of_the_copy():
    import copy
    import pickle

    a = np.zeros(2)
    for clone in (copy.deepcopy(Packed(a, 2)), pickle.loads(pickle.dumps(Packed(a, 2)))):
        assert clone.arr is not a
        clone.put(3.0, 4.0)
        assert clone.arr.tolist() == [3.0, 4.0] and a.tolist() == [0.0, 0.0]
