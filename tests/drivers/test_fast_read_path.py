"""The bus's Fast Sync Read path without links (``DxlBus._read_fast``: one servo at most on each
ID) against the general path it stands for (every answer as a link, then ``_send_fast``).

Both buses get the same packets: Fast Sync Reads of IDs in any order, some nobody has (the
blocks stop there, the header still announces them all, the servos after it are still read),
some twice, of Present Position or of the tick block through Indirect Data, with the servos
moving between them; the bytes, when each arrives and is readable, the trace and the
counters agree. No wall-clock time is measured.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

import drivers.protocol2.control_table as ct
from drivers.clock import VirtualClock
from drivers.dxlsim.bus import DxlBus
from drivers.dxlsim.protocol import Instruction, encode_instruction
from drivers.dxlsim.servo import VirtualServo

PRESENT_POSITION, GOAL_POSITION, TORQUE = 132, 116, 64


def _bus(n: int, latency_ms: float, general: bool) -> DxlBus:
    clock = VirtualClock()
    servos = [VirtualServo("XM430-W350", i, baud=1_000_000, return_delay_us=0) for i in range(n)]
    bus = DxlBus(servos, baud=1_000_000, clock=clock, latency_timer_ms=latency_ms, trace=True)
    for s in servos:
        assert s.write(ct.INDIRECT_ADDRESS_1.addr, ct.tick_block_targets(), 0.0) == 0
        assert s.write(TORQUE, b"\x01", 0.0) == 0
    if general:

        def links_path(items, one, t):  # the general path's links, then its _send_fast
            links = []
            for sid, addr, length in items:
                s = one.get(sid)
                if s is None:
                    links.append(([], length))
                else:
                    s.touch(t)
                    links.append(([(s, *s.read(addr, length, t))], length))
            bus._send_fast(links, t)

        bus._read_fast = links_path
    return bus


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 8),
    latency_ms=st.sampled_from((0.0, 1.0, 16.0)),
    steps=st.lists(
        st.tuples(
            st.lists(st.integers(0, 10), min_size=1, max_size=10),  # IDs asked, in order
            st.booleans(),  # the tick block, else Present Position
            st.integers(0, 4095),  # a goal for everyone before the read
            st.sampled_from((1e-4, 0.004, 0.02)),  # then the host waits
        ),
        min_size=1,
        max_size=6,
    ),
)
def test_fast_read_without_links_equals_the_general_path(n, latency_ms, steps):
    a, b = (_bus(n, latency_ms, general) for general in (False, True))
    for ids, block, goal, wait in steps:
        addr, size = (ct.INDIRECT_DATA_1.addr, ct.TICK_BLOCK_SIZE) if block else (132, 4)
        goals = b"".join(bytes((i,)) + goal.to_bytes(4, "little") for i in range(n))
        write = encode_instruction(0xFE, Instruction.SYNC_WRITE, bytes((116, 0, 4, 0)) + goals)
        read = encode_instruction(
            0xFE, Instruction.FAST_SYNC_READ, bytes((addr & 0xFF, addr >> 8, size, 0, *ids))
        )
        for bus in (a, b):
            bus.write(write)
            bus.write(read)
            bus.clock.advance(wait)
            bus.read(bus.in_waiting() // 2)
        assert (a._rx_data, a._rx_wire, a._rx_vis) == (b._rx_data, b._rx_wire, b._rx_vis)
    assert a.trace == b.trace and a.stats == b.stats
    assert [s.now for s in a.servos] == [s.now for s in b.servos]
