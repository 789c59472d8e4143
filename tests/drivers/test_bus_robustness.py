"""Arbitrary bytes never crash the emulator, nor change a servo unless they hold a valid packet."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dxlsim.protocol import Instruction, StreamParser, encode_instruction
from tests.drivers.conftest import make_bus


def _writable_snapshot(bus):
    t = bus.clock.now()
    snap = {}
    for s in bus.servos:
        for f in s.model.fields:
            if f.access == "RW" and f.addr != 98:  # watchdog reads -1 once tripped by time
                snap[(s.id, f.addr)] = s.read(f.addr, f.size, t)
    return snap


@settings(max_examples=150, deadline=None)
@given(st.lists(st.binary(min_size=1, max_size=80), min_size=1, max_size=6))
def test_garbage_never_raises_and_never_changes_state(chunks):
    bus = make_bus((1, 2))
    before = _writable_snapshot(bus)
    parser = StreamParser()
    valid = []
    for chunk in chunks:
        valid += [f for f in parser.feed(chunk) if f.crc_ok]
        bus.write(chunk)
        bus.read(10_000, bus.clock.now() + 1.0)
    if not valid:
        assert _writable_snapshot(bus) == before


packets = st.builds(
    lambda sid, addr, value: encode_instruction(sid, Instruction.WRITE, bytes([addr, 0, value])),
    st.sampled_from([1, 2]),
    st.sampled_from([65, 68]),
    st.integers(0, 1),
)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=20), packets), min_size=1, max_size=8))
def test_valid_packets_among_garbage_are_executed(pieces):
    bus = make_bus((1, 2))
    for piece in pieces:
        bus.write(piece)
        bus.clock.advance(0.002)  # > 1.5 ms: a partial packet from garbage is dropped
    stream_frames = []
    for piece in pieces:
        p = StreamParser()
        stream_frames += [f.packet for f in p.feed(piece) if f.crc_ok]
    # The last valid write to each (id, addr) is what the servo holds.
    expected = {}
    for pkt in stream_frames:
        if pkt.instruction == Instruction.WRITE:
            expected[(pkt.id, pkt.params[0])] = pkt.params[2]
    t = bus.clock.now()
    for (sid, addr), value in expected.items():
        assert bus.servo(sid).read(addr, 1, t) == (0, bytes([value]))
