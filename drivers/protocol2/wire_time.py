"""The wire-time model of one control cycle: the physical limit every measurement is set beside.

One cycle is a Sync Write of ``data_bytes`` (Goal Position, 4 B) to N servos and a Sync Read
(plain or Fast) of ``data_bytes`` (Present Position, 4 B) from them, back to back, 8N1 (10 bit
times per byte)::

    Sync Write            14 + N·(1 + X)      no reply
    Sync Read request     14 + N
    plain replies         N·(11 + X)          each servo waits its Return Delay Time + turnaround
    Fast reply            8 + N·(X + 4)       one packet: one Return Delay Time + turnaround

With X = 4 that is 28 + 21N bytes (plain) and 36 + 14N bytes (fast), and

    cycle time = 10·bytes/baud + n_d·(RDT + turnaround) + L

with n_d = N (plain) or 1 (fast) and L the USB adapter's latency timer, paid once per read
transaction: the adapter sends the last bytes of the reply when the line has been quiet for L,
unless they filled a whole 62-byte USB packet (then they go at once). Host CPU time is not in
the model: the ratio achieved/model is what the host loses.
"""

from __future__ import annotations

from collections.abc import Sequence

#: Bytes an FTDI adapter passes to the host per USB packet (64 minus 2 status bytes).
USB_CHUNK = 62
#: Adapter latency assumed for a pseudo-terminal (ms). A pty has no latency timer: the
#: process serving it (``hilsim emulate``) writes each piece of a reply (back-to-back bytes, at
#: most 62, as a USB adapter delivers them) when its last byte is due and is
#: woken within ~0.1-1 ms on a quiet host. The host counts this for a pty in its bus-capacity
#: check; the emulator tells its users to put it in their rig.
PTY_LATENCY_MS = 1.0
#: Servo turnaround assumed when nothing better is known (AX-12 ≈ 20 µs; not published for X).
DEFAULT_TURNAROUND_S = 20e-6
#: Bit times per byte on the wire: 8N1 (start bit, 8 data bits, stop bit).
BITS_PER_BYTE = 10
#: Bytes of one unicast Read instruction: header 4, ID, LEN 2, INST, address 2, length 2, CRC 2.
READ_INSTRUCTION_BYTES = 14
#: Bytes of a Fast Sync Read reply before the first servo's block: header 4, ID, LEN 2, INST.
FAST_REPLY_HEADER_BYTES = 8


def wire_time_s(n_bytes: int, baud: float) -> float:
    """Time (s) ``n_bytes`` take on the wire at ``baud`` bit/s."""
    return BITS_PER_BYTE * n_bytes / baud


def status_bytes(data_bytes: int = 0) -> int:
    """Bytes of one status packet carrying ``data_bytes``: header 4, ID, LEN 2, INST, ERR,
    the data, CRC 2."""
    return 11 + data_bytes


def fast_block_bytes(data_bytes: int = 4) -> int:
    """Bytes one servo adds to a Fast Sync Read reply: ERR, ID, the data, CRC 2."""
    return data_bytes + 4


def read_bytes(data_bytes: int) -> int:
    """Bytes on the wire of one unicast Read of ``data_bytes``: the instruction and the
    status packet with the data."""
    return READ_INSTRUCTION_BYTES + status_bytes(data_bytes)


def chain_rest_s(
    fast: bool, delays_s: Sequence[float], first: bool, byte_s: float, data_bytes: int = 4
) -> float:
    """Longest the replies of a Sync Read's servos from one place of its chain on can still
    take, if the one there started late (the adapter's latency not included): their wire
    time, Return Delay Times and turnaround (``delays_s``, in chain order from that place:
    one of each in a Fast Sync Read, every one in a plain chain; in a Fast reply the header
    too if the place is the ``first``). 0.45 ms for four fast servos at 1 Mbps, Return Delay
    Time 0."""
    if fast:  # (header if it is still to come) + ERR ID data CRC(2) each
        head = FAST_REPLY_HEADER_BYTES if first else 0
        return (fast_block_bytes(data_bytes) * len(delays_s) + head) * byte_s + delays_s[0]
    return status_bytes(data_bytes) * len(delays_s) * byte_s + sum(delays_s)


def sync_write_bytes(n: int, data_bytes: int = 4) -> int:
    """Bytes on the wire of one Sync Write of ``data_bytes`` to ``n`` servos."""
    return 14 + n * (1 + data_bytes)


def read_request_bytes(n: int) -> int:
    """Bytes of a (Fast) Sync Read request naming ``n`` servos."""
    return 14 + n


def read_reply_bytes(n: int, fast: bool, data_bytes: int = 4) -> int:
    """Bytes the servos send back: ``n`` status packets (plain) or one Fast Sync Read packet."""
    if fast:
        return FAST_REPLY_HEADER_BYTES + n * fast_block_bytes(data_bytes)
    return n * status_bytes(data_bytes)


def cycle_bytes(n: int, fast: bool, data_bytes: int = 4, read_data_bytes: int | None = None) -> int:
    """All bytes of one write+read cycle: 28 + 21N (plain) or 36 + 14N (fast) for 4-byte data.
    ``read_data_bytes``: what each servo's reply carries, when not ``data_bytes`` (the X
    series' tick block: 8, 40 + 18N fast)."""
    read = data_bytes if read_data_bytes is None else read_data_bytes
    return sync_write_bytes(n, data_bytes) + read_request_bytes(n) + read_reply_bytes(n, fast, read)


def latency_term_s(reply_bytes: int, latency_s: float) -> float:
    """What the adapter's latency timer adds to one read transaction (s)."""
    if latency_s <= 0.0 or reply_bytes % USB_CHUNK == 0:
        return 0.0
    return latency_s


def cycle_time_s(
    n: int,
    baud: float,
    fast: bool,
    *,
    return_delay_s: float | Sequence[float] = 0.0,
    turnaround_s: float = DEFAULT_TURNAROUND_S,
    latency_s: float = 0.0,
    data_bytes: int = 4,
    read_data_bytes: int | None = None,
) -> float:
    """Model time (s) of one write+read cycle with ``n`` servos at ``baud`` bit/s.

    ``return_delay_s`` is one Return Delay Time for every servo or one per servo (in read
    order); plain Sync Read pays each servo's, Fast Sync Read only the first servo's.
    ``read_data_bytes``: the read's bytes per servo when not ``data_bytes``.
    """
    if n < 1 or baud <= 0:
        raise ValueError(f"need n >= 1 and baud > 0, got n={n}, baud={baud}")
    rdts = (
        [float(return_delay_s)] * n
        if isinstance(return_delay_s, int | float)
        else list(return_delay_s)
    )
    if len(rdts) != n:
        raise ValueError(f"{len(rdts)} return delays for {n} servos")
    delays = rdts[0] + turnaround_s if fast else sum(rdts) + n * turnaround_s
    read = data_bytes if read_data_bytes is None else read_data_bytes
    wire = 10.0 * cycle_bytes(n, fast, data_bytes, read) / baud
    return wire + delays + latency_term_s(read_reply_bytes(n, fast, read), latency_s)


def cycle_rate_hz(
    n: int,
    baud: float,
    fast: bool,
    *,
    return_delay_s: float | Sequence[float] = 0.0,
    turnaround_s: float = DEFAULT_TURNAROUND_S,
    latency_s: float = 0.0,
    data_bytes: int = 4,
    read_data_bytes: int | None = None,
) -> float:
    """``1 / cycle_time_s(...)``: the most write+read cycles per second the bus allows."""
    return 1.0 / cycle_time_s(
        n,
        baud,
        fast,
        return_delay_s=return_delay_s,
        turnaround_s=turnaround_s,
        latency_s=latency_s,
        data_bytes=data_bytes,
        read_data_bytes=read_data_bytes,
    )
