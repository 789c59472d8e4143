"""The emulator's fast paths (issue 12) against the plain definitions they replace.

Each fast path must give the same result, bit for bit, as the simple code it stands for:
the two-byte CRC table against the byte loop it replaced and the bitwise definition, the
incremental USB visibility of :class:`~drivers.dxlsim.bus.DxlBus` against
:func:`~drivers.dxlsim.usb.full_visibility` recomputed from scratch after every burst of reply
bytes, a Fast Sync Read reply put on the wire at once against block by block, the parser's
whole-frame shortcut against the same bytes fed one at a time. No wall-clock time is measured.
"""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.clock import VirtualClock
from drivers.dxlsim.bus import DxlBus
from drivers.dxlsim.protocol import HEADER, Instruction, StreamParser, encode_instruction
from drivers.dxlsim.servo import VirtualServo
from drivers.dxlsim.usb import full_visibility
from drivers.protocol2.crc import CRC_TABLE, crc16, crc16_blocks, make_word_table
from drivers.protocol2.wire_time import USB_CHUNK


def reference_crc16(data, crc: int = 0) -> int:
    """Protocol 2.0's CRC bit by bit: polynomial 0x8005, MSB first, no table."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def table_crc16(data, crc: int = 0) -> int:
    """The byte-at-a-time loop crc16 was before the two-byte table."""
    for byte in data:
        crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_crc16_equals_the_bitwise_definition(data, crc):
    expected = reference_crc16(data, crc)
    assert table_crc16(data, crc) == expected
    assert crc16(data, crc) == expected
    assert crc16(bytearray(data), crc) == expected
    assert crc16(memoryview(b"\x00" + data)[1:], crc) == expected  # an unaligned view
    assert crc16(list(data), crc) == expected  # not a buffer: the byte loop


@given(st.binary(max_size=100), st.binary(max_size=100), st.integers(0, 0xFFFF))
def test_crc16_continues_across_pieces(a, b, crc):
    assert crc16(b, crc16(a, crc)) == crc16(a + b, crc)


@given(st.lists(st.binary(max_size=12), max_size=20), st.integers(0, 0xFFFF))
def test_crc16_blocks_runs_on_over_each_blocks_crc(bodies, crc):
    expected = []
    line = b""
    for body in bodies:
        line += body
        block_crc = reference_crc16(line, crc)
        expected.append(block_crc)
        line += bytes((block_crc & 0xFF, block_crc >> 8))
    assert crc16_blocks(bodies, crc) == expected


def test_crc_tables_against_the_definition():
    assert list(CRC_TABLE) == [reference_crc16(bytes((i,))) for i in range(256)]
    # the big-endian word table, used on big-endian machines, checked here by hand
    words = make_word_table(little=False)
    for data, crc in ((bytes(range(40)), 0), (b"\xff\xff\xfd\x00\xfe" * 7 + b"\x01", 0x1234)):
        r = crc
        for (w,) in struct.iter_unpack(">H", data):
            r = words[r ^ w]
        assert r == reference_crc16(data, crc)


def test_known_packet_crc():
    # e-Manual protocol2.md, Ping example: FF FF FD 00 01 03 00 01 -> CRC 19 4E
    assert crc16(b"\xff\xff\xfd\x00\x01\x03\x00\x01") == 0x4E19


# --- USB visibility ----------------------------------------------------------------------

# One step of host/bus traffic: a burst of reply bytes (size, where it starts relative to the
# last byte on the wire: contiguous, a gap around the latency timer, or a late reply that
# starts before it), a read of some bytes, a reset, or the clock moving on.
_gap = st.sampled_from((0.0, 1e-6, 0.5, 0.999999, 1.0, 1.000001, 1.5, 3.0, -0.5, -3.0))
_burst = st.tuples(st.just("emit"), st.integers(1, 150), _gap)
_read = st.tuples(st.just("read"), st.integers(0, 200), st.just(0.0))
_reset = st.tuples(st.just("reset"), st.just(0), st.just(0.0))
_wait = st.tuples(st.just("wait"), st.just(0), st.sampled_from((0.0, 0.2, 1.0, 1.01, 2.0, 40.0)))


@given(
    latency_ms=st.sampled_from((1.0, 16.0, 1.0, 16.0, 0.0)),
    baud=st.sampled_from((9_600, 57_600, 1_000_000, 4_000_000)),
    steps=st.lists(st.one_of(_burst, _burst, _read, _reset, _wait), max_size=40),
)
def test_incremental_visibility_equals_the_full_recomputation(latency_ms, baud, steps):
    """After every burst (latency timer 0 = an ideal adapter: each byte at its stop bit)."""
    clock = VirtualClock(3.0)
    bus = DxlBus([], baud=baud, clock=clock, latency_timer_ms=latency_ms)
    latency = bus.latency_s
    for kind, size, x in steps:
        if kind == "emit":
            last = bus._rx_wire[-1] if bus._rx_wire else clock.now()
            start = max(0.0, last + x * (latency or 1e-3))  # x in units of the latency timer
            old = list(bus._rx_vis)
            bus._emit(bytes(size), start, "")
            expected = (
                full_visibility(bus._rx_wire, old, clock.now(), latency)
                if latency
                else bus._rx_wire
            )
            assert bus._rx_vis == expected
            assert len(bus._rx_vis) == len(bus._rx_wire) == len(bus._rx_data)
        elif kind == "read":
            bus.read(size)
        elif kind == "reset":
            bus.reset_input()
        else:
            clock.advance(x * (latency or 1e-3))


def test_visibility_of_a_long_burst_in_chunks_of_62():
    clock = VirtualClock()
    bus = DxlBus([], baud=1_000_000, clock=clock, latency_timer_ms=16.0)
    bt = bus.byte_time
    start = 1.0
    for size in (8, 60, 70):  # one reply in three bursts back to back: 138 bytes
        old = list(bus._rx_vis)
        start = bus._emit(bytes(size), start, "")
        assert bus._rx_vis == full_visibility(bus._rx_wire, old, clock.now(), bus.latency_s)
    vis = bus._rx_vis
    wire = bus._rx_wire
    assert wire[-1] == pytest.approx(1.0 + 138 * bt)
    assert vis[:USB_CHUNK] == [wire[USB_CHUNK - 1]] * USB_CHUNK  # full: sent at once
    assert vis[USB_CHUNK : 2 * USB_CHUNK] == [wire[2 * USB_CHUNK - 1]] * USB_CHUNK
    assert vis[2 * USB_CHUNK :] == [wire[-1] + bus.latency_s] * 14  # the rest: the timer


# --- the instruction parser --------------------------------------------------------------


def _frames_of(chunks):
    parser = StreamParser()
    frames = [f for chunk in chunks for f in parser.feed(chunk)]
    return frames, parser.pending, parser.skipped


_packet = st.builds(
    encode_instruction,
    st.integers(0, 0xFE),
    st.sampled_from(list(Instruction)),
    st.binary(max_size=20) | st.just(b"\xff\xff\xfd\x00"),
)
_damaged = _packet.flatmap(
    lambda p: st.integers(0, len(p) - 1).map(lambda i: p[:i] + bytes((p[i] ^ 0x5A,)) + p[i + 1 :])
)
_short = st.binary(min_size=3, max_size=3).map(lambda rest: HEADER + b"\x01\x00\x00" + rest)


@given(st.lists(_packet | _damaged | _short | st.binary(max_size=12), max_size=12))
def test_parser_whole_frames_equal_byte_by_byte(chunks):
    """A chunk that is exactly one frame takes the parser's shortcut; fed one byte at a time
    the same stream never does: the frames, what is held and what was skipped agree."""
    stream = b"".join(chunks)
    assert _frames_of(chunks) == _frames_of([stream[i : i + 1] for i in range(len(stream))])


# --- a Fast Sync Read reply put on the wire at once ----------------------------------------


def _fast_read_bus(latency_ms: float, n: int, burst: bool) -> DxlBus:
    clock = VirtualClock()
    servos = [VirtualServo("XM430-W350", i, baud=1_000_000, return_delay_us=0) for i in range(n)]
    bus = DxlBus(servos, baud=1_000_000, clock=clock, latency_timer_ms=latency_ms, trace=True)
    if not burst:
        bus._emit_burst = lambda groups, start: False  # every block through _emit_group
    return bus


@given(
    latency_ms=st.sampled_from((1.0, 16.0)),
    n=st.integers(1, 20),
    steps=st.lists(
        st.tuples(st.integers(1, 20), st.integers(0, 300), st.sampled_from((0.0, 1e-4, 0.02))),
        max_size=8,
    ),
)
def test_fast_reply_at_once_equals_block_by_block(latency_ms, n, steps):
    """Each step: a Fast Sync Read of the first ``k`` IDs, then the host reads ``r`` bytes
    and waits ``w`` s, so replies pile up unread across chunk boundaries."""
    a, b = (_fast_read_bus(latency_ms, n, burst) for burst in (True, False))
    for k, r, w in steps:
        packet = encode_instruction(
            0xFE, Instruction.FAST_SYNC_READ, bytes((132, 0, 4, 0, *range(min(k, n))))
        )
        for bus in (a, b):
            bus.write(packet)
            bus.clock.advance(w)
            bus.read(r)
        assert (a._rx_data, a._rx_wire, a._rx_vis) == (b._rx_data, b._rx_wire, b._rx_vis)
    assert a.trace == b.trace and a.stats == b.stats
