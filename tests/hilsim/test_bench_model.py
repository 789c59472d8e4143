"""The wire-time model against the Protocol 2.0 packet sizes and the theoretical rate table."""

from __future__ import annotations

import pytest

from drivers.protocol2.wire_time import (
    USB_CHUNK,
    cycle_bytes,
    cycle_rate_hz,
    cycle_time_s,
    latency_term_s,
    read_reply_bytes,
    read_request_bytes,
    sync_write_bytes,
)

# Theoretical loop rate, 10 bits per byte of 28 + 21N (plain) or 36 + 14N (fast) bytes
# (RDT = 0, t_proc = 0), plain / fast, Hz.
TABLE = {
    (1, 57_600): (118, 115),
    (4, 57_600): (51, 63),
    (8, 57_600): (29, 39),
    (16, 57_600): (16, 22),
    (1, 1_000_000): (2041, 2000),
    (4, 1_000_000): (893, 1087),
    (8, 1_000_000): (510, 676),
    (16, 1_000_000): (275, 385),
    (1, 2_000_000): (4082, 4000),
    (4, 2_000_000): (1786, 2174),
    (8, 2_000_000): (1020, 1351),
    (16, 2_000_000): (549, 769),
    (1, 4_000_000): (8163, 8000),
    (4, 4_000_000): (3571, 4348),
    (8, 4_000_000): (2041, 2703),
    (16, 4_000_000): (1099, 1538),
}


@pytest.mark.parametrize("n", range(1, 33))
def test_cycle_bytes_are_the_reference_formulas(n):
    assert cycle_bytes(n, fast=False) == 28 + 21 * n
    assert cycle_bytes(n, fast=True) == 36 + 14 * n
    # and the packet sizes they are made of (Protocol 2.0 multi-servo packets, X = 4)
    assert sync_write_bytes(n) == 14 + 5 * n
    assert read_request_bytes(n) == 14 + n
    assert read_reply_bytes(n, fast=False) == 15 * n
    assert read_reply_bytes(n, fast=True) == 8 + 8 * n


@pytest.mark.parametrize(("n", "baud"), sorted(TABLE))
def test_theoretical_rate_table(n, baud):
    plain = cycle_rate_hz(n, baud, False, turnaround_s=0.0)
    fast = cycle_rate_hz(n, baud, True, turnaround_s=0.0)
    assert (round(plain), round(fast)) == TABLE[(n, baud)]


def test_factory_return_delay_at_1m_with_4_servos():
    """The factory Return Delay Time (500 µs) at 1 Mbps, N = 4: 321 / 704 Hz."""
    kw = dict(return_delay_s=500e-6, turnaround_s=0.0)
    assert round(cycle_rate_hz(4, 1_000_000, False, **kw)) == 321
    assert round(cycle_rate_hz(4, 1_000_000, True, **kw)) == 704


def test_delays_plain_pays_every_servo_fast_pays_the_first():
    rdts = [100e-6, 200e-6, 300e-6]
    wire_plain = 10 * cycle_bytes(3, False) / 1e6
    wire_fast = 10 * cycle_bytes(3, True) / 1e6
    t_plain = cycle_time_s(3, 1e6, False, return_delay_s=rdts, turnaround_s=20e-6)
    t_fast = cycle_time_s(3, 1e6, True, return_delay_s=rdts, turnaround_s=20e-6)
    assert t_plain == pytest.approx(wire_plain + 600e-6 + 3 * 20e-6, rel=1e-12)
    assert t_fast == pytest.approx(wire_fast + 100e-6 + 20e-6, rel=1e-12)


def test_latency_timer_once_per_read_unless_the_reply_fills_usb_packets():
    assert latency_term_s(15, 16e-3) == 16e-3
    assert latency_term_s(2 * USB_CHUNK, 16e-3) == 0.0  # full packets go at once
    assert latency_term_s(15, 0.0) == 0.0
    base = cycle_time_s(4, 1e6, True)
    assert cycle_time_s(4, 1e6, True, latency_s=1e-3) == pytest.approx(base + 1e-3, rel=1e-12)


def test_bad_arguments():
    with pytest.raises(ValueError):
        cycle_time_s(0, 1e6, True)
    with pytest.raises(ValueError):
        cycle_time_s(2, 1e6, True, return_delay_s=[0.0])
