"""Wire timing of the emulated bus, measured through the unmodified SDK on the virtual clock.

Every expectation is computed from the wire-time model (drivers/protocol2/wire_time.py): 10 bits
per byte, each servo's Return Delay Time, the turnaround, and the USB latency timer.
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

from drivers.dxlsim import unregister_bus
from tests.drivers.conftest import make_bus, open_session

OK = sdk.COMM_SUCCESS
ADDR_GOAL_POS, ADDR_PRESENT_POS = 116, 132


@pytest.fixture
def opened():
    sessions = []

    def _open(bus, **kw):
        s = open_session(bus, **kw)
        sessions.append(s)
        return s

    yield _open
    for s in sessions:
        s.port.closePort()
    unregister_bus("test-bus")


@pytest.mark.parametrize("baud", [57_600, 1_000_000, 4_000_000])
@pytest.mark.parametrize("rdt_us", [0.0, 500.0])
@pytest.mark.parametrize("latency_ms", [0.0, 1.0, 16.0])
def test_single_transaction_time(opened, baud, rdt_us, latency_ms):
    turnaround_us = 20.0
    bus = make_bus(
        (1,),
        baud=baud,
        rdt_us=rdt_us,
        turnaround_us=turnaround_us,
        latency_timer_ms=latency_ms,
        trace=True,
    )
    s = opened(bus, latency_timer_ms=max(latency_ms, 16.0))
    t0 = bus.clock.now()
    _value, result, error = s.ph.read4ByteTxRx(s.port, 1, ADDR_PRESENT_POS)
    assert (result, error) == (OK, 0)
    elapsed = bus.clock.now() - t0
    wire = 10 * (14 + 15) / baud  # Read instruction 14 B + status with 4 data bytes 15 B
    expected = wire + rdt_us * 1e-6 + turnaround_us * 1e-6 + latency_ms * 1e-3
    assert elapsed == pytest.approx(expected, abs=1e-6)
    # The trace agrees: first instruction byte to last reply byte on the wire.
    tx, rx = bus.trace[-2], bus.trace[-1]
    assert (tx.direction, rx.direction) == ("tx", "rx")
    assert rx.t_end - tx.t_start == pytest.approx(expected - latency_ms * 1e-3, abs=1e-9)


# Theoretical loop rates of the wire-time model (RDT = 0, t_proc = 0), plain / fast, Hz.
TABLE = {
    (1, 1_000_000): (2041, 2000),
    (4, 1_000_000): (893, 1087),
    (8, 1_000_000): (510, 676),
    (16, 1_000_000): (275, 385),
    (1, 4_000_000): (8163, 8000),
    (4, 4_000_000): (3571, 4348),
    (8, 4_000_000): (2041, 2703),
    (16, 4_000_000): (1099, 1538),
}


def _cycle(s, ids, fast: bool) -> None:
    writer = sdk.GroupSyncWrite(s.port, s.ph, ADDR_GOAL_POS, 4)
    for i in ids:
        writer.addParam(i, list((2048).to_bytes(4, "little")))
    reader = sdk.GroupSyncRead(s.port, s.ph, ADDR_PRESENT_POS, 4)
    for i in ids:
        reader.addParam(i)
    assert writer.txPacket() == OK
    assert (reader.fastSyncRead() if fast else reader.txRxPacket()) == OK


@pytest.mark.parametrize(("n", "baud"), sorted(TABLE))
@pytest.mark.parametrize("fast", [False, True], ids=["plain", "fast"])
def test_cycle_time_matches_wire_model_table(opened, n, baud, fast):
    ids = tuple(range(1, n + 1))
    bus = make_bus(ids, baud=baud, rdt_us=0.0, turnaround_us=0.0)
    s = opened(bus)
    for i in ids:
        assert s.ph.write1ByteTxRx(s.port, i, 64, 1) == (OK, 0)
    t0 = bus.clock.now()
    _cycle(s, ids, fast)
    elapsed = bus.clock.now() - t0
    n_bytes = 36 + 14 * n if fast else 28 + 21 * n
    assert elapsed == pytest.approx(10 * n_bytes / baud, abs=1e-6)
    assert round(1 / elapsed) == TABLE[(n, baud)][fast]


@pytest.mark.parametrize(("fast", "expected_hz"), [(False, 321), (True, 704)])
def test_factory_return_delay_rates(opened, fast, expected_hz):
    """With the factory Return Delay Time (500 µs) at 1 Mbps, N = 4: 321 / 704 Hz."""
    ids = (1, 2, 3, 4)
    bus = make_bus(ids, rdt_us=500.0, turnaround_us=0.0)
    s = opened(bus)
    t0 = bus.clock.now()
    _cycle(s, ids, fast)
    assert round(1 / (bus.clock.now() - t0)) == expected_hz


def test_latency_timer_holds_bytes_until_line_is_quiet():
    bus = make_bus((1,), latency_timer_ms=16.0)
    from drivers.dxlsim.protocol import Instruction, encode_instruction

    t_end = bus.write(encode_instruction(1, Instruction.PING))
    last_byte = t_end + 20e-6 + 14 * 10 / bus.baud
    assert bus.in_waiting(last_byte + 15.9e-3) == 0
    assert bus.in_waiting(last_byte + 16.0e-3) == 14


def test_usb_chunk_of_62_bytes_is_sent_without_waiting():
    bus = make_bus((1,), latency_timer_ms=16.0)
    from drivers.dxlsim.protocol import Instruction, encode_instruction

    # Read 60 bytes -> a 71-byte status: the first 62 bytes flush as soon as they are in.
    t_end = bus.write(encode_instruction(1, Instruction.READ, bytes([64, 0, 60, 0])))
    t62 = t_end + 20e-6 + 62 * 10 / bus.baud
    assert bus.in_waiting(t62 - 1e-9) == 0
    assert bus.in_waiting(t62) == 62
    assert bus.in_waiting(t62 + 16e-3) == 62  # the rest waits out the timer
    assert bus.in_waiting(t_end + 20e-6 + 71 * 10 / bus.baud + 16e-3) == 71


def test_servo_on_another_baud_rate_never_answers(opened):
    bus = make_bus((1,), baud=57_600)  # servos at 57600 ...
    s = opened(bus)
    s.port.setBaudRate(1_000_000)  # ... host at 1 Mbps: they hear noise
    assert s.ph.ping(s.port, 1)[1] == sdk.COMM_RX_TIMEOUT
    s.port.setBaudRate(57_600)
    assert s.ph.ping(s.port, 1)[1] == OK


def test_changing_the_host_baud_rate_100_times_costs_nothing_cumulative(opened):
    """A baud scan, or the SDK's factory_reset example, switches the host's rate again and
    again: each reply still takes its wire time, and the emulator's byte-time table (one
    entry per byte of the longest burst) does not grow with the number of changes."""
    from drivers.clock import VirtualClock
    from drivers.dxlsim import DxlBus, VirtualServo

    rates = {1: 57_600, 2: 1_000_000}  # one servo at each rate
    servos = [VirtualServo("XM430-W350", i, baud=b, return_delay_us=0.0) for i, b in rates.items()]
    bus = DxlBus(servos, baud=57_600, clock=VirtualClock(), turnaround_us=20.0)
    s = opened(bus)
    sizes = set()
    for change in range(100):
        sid = 1 + change % 2
        s.port.setBaudRate(rates[sid])
        t0 = bus.clock.now()
        assert s.ph.ping(s.port, sid)[1] == OK
        # Ping 10 B + its status 14 B, then the turnaround: the same on the 100th change
        assert bus.clock.now() - t0 == pytest.approx(10 * 24 / rates[sid] + 20e-6, abs=1e-9)
        sizes.add(len(bus._steps))
        assert sizes == {256}, f"byte-time table after {change + 1} changes: {sorted(sizes)}"


def test_inter_byte_gap_over_1_5_ms_drops_the_packet():
    from drivers.dxlsim.protocol import Instruction, encode_instruction

    bus = make_bus((1,))
    frame = encode_instruction(1, Instruction.WRITE, bytes([65, 0, 1]))
    bus.write(frame[:5])
    bus.clock.advance(2e-3)
    bus.write(frame[5:])
    assert bus.servo(1).read(65, 1, bus.clock.now())[1] == b"\x00"
    bus.clock.advance(1e-3)
    bus.write(frame[:5])
    bus.clock.advance(1e-3)  # under the limit: still one packet
    bus.write(frame[5:])
    assert bus.servo(1).read(65, 1, bus.clock.now() + 1e-3)[1] == b"\x01"


def test_the_rest_of_a_broken_chain_is_its_bytes_and_delays_from_that_place():
    from drivers.protocol2.wire_time import chain_rest_s

    byte_s, d = 1e-5, [100e-6, 200e-6, 300e-6]  # Return Delay + turnaround, chain order
    # Fast: the header only if the first servo is missing, one delay (the first's)
    assert chain_rest_s(True, d, True, byte_s) == pytest.approx((8 + 3 * 8) * byte_s + 100e-6)
    assert chain_rest_s(True, d[1:], False, byte_s) == pytest.approx(2 * 8 * byte_s + 200e-6)
    # plain: a status packet and a delay each, longer for a longer read
    assert chain_rest_s(False, d, True, byte_s, 5) == pytest.approx(3 * 16 * byte_s + 600e-6)
