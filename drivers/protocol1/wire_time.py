"""The wire-time model of one control cycle on a Protocol 1.0-framed bus, per read method.

A cycle is one SYNC WRITE of ``data_bytes`` to N servos (no reply) and the reads, 8N1::

    SYNC WRITE             8 + N·(1 + X)         no reply
    SYNC READ request      8 + N                 Feetech STS/SMS: then N status packets
    BULK READ request      7 + 3N                Dynamixel MX: then N status packets
    READ (one servo)       8                     then one status packet; one round trip each
    status packet          6 + X                 after Return Delay Time + turnaround

    time = 10·bytes/baud + (each reply's RDT + turnaround) + L per read transaction

with L the USB adapter's latency timer (once per transaction: N times for single reads).
For 12 servos at 1 Mbit/s, 2-byte data, RDT 0: Sync Write 0.44 ms, Sync Read 1.16 ms, Bulk
Read 1.39 ms, single reads 1.92 ms on the wire alone, plus 20 µs turnaround a reply.
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import StrEnum

BITS_PER_BYTE = 10
#: Servo processing time after its Return Delay Time (AX-12 ≈ 20 µs; the same default as P2).
DEFAULT_TURNAROUND_S = 20e-6
#: Bytes of one READ instruction: FF FF ID LEN 02 addr len CHK.
READ_INSTRUCTION_BYTES = 8
#: Return Delay Time unit, all families (2 µs a count).
RETURN_DELAY_UNIT_S = 2e-6


class ReadMethod(StrEnum):
    SYNC_READ = "sync_read"  # Feetech STS/SMS 0x82
    BULK_READ = "bulk_read"  # Dynamixel MX 0x92
    SINGLE = "single"  # one READ per servo (AX, SCS)


def wire_time_s(n_bytes: int, baud: float) -> float:
    """Time (s) ``n_bytes`` take on the wire at ``baud`` bit/s."""
    return BITS_PER_BYTE * n_bytes / baud


def status_bytes(data_bytes: int = 0) -> int:
    """Bytes of one status packet carrying ``data_bytes``."""
    return 6 + data_bytes


def sync_write_bytes(n: int, data_bytes: int = 2) -> int:
    return 8 + n * (1 + data_bytes)


def sync_read_request_bytes(n: int) -> int:
    return 8 + n


def bulk_read_request_bytes(n: int) -> int:
    return 7 + 3 * n


def read_bytes(data_bytes: int = 2) -> int:
    """One READ and its status packet."""
    return READ_INSTRUCTION_BYTES + status_bytes(data_bytes)


def read_cycle_bytes(n: int, method: ReadMethod | str, data_bytes: int = 2) -> int:
    """Bytes of reading ``data_bytes`` from each of ``n`` servos."""
    method = ReadMethod(method)
    if method is ReadMethod.SINGLE:
        return n * read_bytes(data_bytes)
    request = (
        sync_read_request_bytes(n) if method is ReadMethod.SYNC_READ else bulk_read_request_bytes(n)
    )
    return request + n * status_bytes(data_bytes)


def cycle_bytes(n: int, method: ReadMethod | str, data_bytes: int = 2) -> int:
    """Sync Write + reads of all ``n`` servos: 16 + 12·N with Sync Read and 2-byte data."""
    return sync_write_bytes(n, data_bytes) + read_cycle_bytes(n, method, data_bytes)


def cycle_time_s(
    n: int,
    baud: float,
    method: ReadMethod | str,
    *,
    return_delay_s: float | Sequence[float] = 0.0,
    turnaround_s: float = DEFAULT_TURNAROUND_S,
    latency_s: float = 0.0,
    data_bytes: int = 2,
    reads: int | None = None,
) -> float:
    """Model time (s) of a Sync Write to ``n`` servos and reads of ``reads`` of them (default
    all; single reads in rotation read fewer per tick). Every reply waits its servo's Return
    Delay Time and the turnaround; L is paid once per read transaction."""
    if n < 1 or baud <= 0:
        raise ValueError(f"need n >= 1 and baud > 0, got n={n}, baud={baud}")
    m = n if reads is None else reads
    rdts = (
        [float(return_delay_s)] * m
        if isinstance(return_delay_s, int | float)
        else list(return_delay_s)[:m]
    )
    method = ReadMethod(method)
    nbytes = sync_write_bytes(n, data_bytes)
    if m:
        nbytes += read_cycle_bytes(m, method, data_bytes)
    transactions = (m if method is ReadMethod.SINGLE else 1) if m else 0
    return wire_time_s(nbytes, baud) + sum(rdts) + m * turnaround_s + transactions * latency_s


def sync_read_time_s(
    n: int,
    baud: float,
    *,
    return_delay_s: float = 0.0,
    turnaround_s: float = DEFAULT_TURNAROUND_S,
    data_bytes: int = 2,
) -> float:
    """A Feetech Sync Read of ``n`` servos alone: request, then each reply after its delay."""
    nbytes = sync_read_request_bytes(n) + n * status_bytes(data_bytes)
    return wire_time_s(nbytes, baud) + n * (return_delay_s + turnaround_s)
