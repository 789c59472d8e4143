"""The USB adapter between the bus and the host: when each received byte becomes readable.

An FTDI-style adapter hands received bytes to the host in chunks: a chunk ends after 62
bytes (readable when its last byte arrives), or when the line has been quiet for the
latency timer (readable ``latency`` after its last byte). A latency of 0 is an ideal port:
every byte is readable when its stop bit ends. :func:`full_visibility` is the definition;
:class:`UsbChunks` computes the same incrementally as reply bursts join the buffer.
"""

from __future__ import annotations

import bisect
import math

from drivers.clock import Clock
from drivers.protocol2.wire_time import USB_CHUNK

__all__ = ["UsbChunks", "chunks", "even_chunks", "full_visibility"]


class UsbChunks:
    """Where the adapter's chunks of the unread bytes start, kept between bursts, so that a
    burst appended at the end re-cuts only the last chunk."""

    def __init__(self, latency: float) -> None:
        #: stream indices where the chunks of the unread bytes start
        self.starts: list[int] = []
        #: the clock and latency the last computation ran with
        self.now = -math.inf
        self.latency = latency

    def forget(self) -> None:
        """The chunks no longer line up (bytes merged out of order): cut them all again."""
        self.starts = []

    def update(
        self,
        wire: list[float],
        vis: list[float],
        base: int,
        clock: Clock,
        latency: float,
        even: bool,
    ) -> list[float]:
        """When each unread byte reaches the host through the USB adapter, after bytes joined
        the buffer (``even``: they came at the end, one burst with no gap over the latency).

        Equal to :func:`full_visibility` (the definition; a test holds the two equal), but it
        only redoes the part that can change. The full computation cuts the unread bytes
        into chunks from the first one: a chunk ends after 62 bytes (readable when its last
        byte arrives), at a gap longer than the latency timer or at the last byte (readable
        ``latency`` after its last byte); then a byte the host could already see keeps its
        earlier time. Bytes appended at the end change neither the chunks that closed before
        the last one nor their times: the same cuts come back, and a kept earlier time is
        kept again (the clock has not gone back). So the chunks are cut again from the last
        chunk's start only, provided the host's reads since ended on a chunk boundary (else
        the chunks start elsewhere now, and all unread bytes are cut again). Inside the last
        chunk and inside one burst there is no gap over the latency, so with ``even`` the
        only possible cut by a gap is where the burst joins the buffer.

        ``wire``: when each unread byte arrives; ``vis``: when each was readable before (the
        new bytes' entries are replaced); ``base``: the stream index of ``wire[0]``. Returns
        the readable times (``vis``, updated in place unless the adapter is ideal).
        """

        if latency <= 0.0:  # an ideal adapter: readable when the stop bit ends
            self.starts = []
            return list(wire)
        now = clock.now()
        m = len(vis)
        starts = self.starts
        lo, kept, incremental = 0, [], False
        if starts and now >= self.now and latency == self.latency:
            i = bisect.bisect_left(starts, base)
            if i < len(starts) and starts[i] == base:
                lo, kept, incremental = starts[-1] - base, starts[i:-1], True
        if even and (incremental or m == 0):
            values, cuts = even_chunks(wire, lo, m, latency)
        else:
            values, cuts = chunks(wire, lo, latency)
        if lo < m and min(vis[lo:m]) <= now:  # a byte the host could already see stays visible
            for j in range(lo, m):
                old = vis[j]
                if old <= now and wire[j] <= old:
                    values[j - lo] = min(values[j - lo], old)
        vis[lo:] = values
        kept.extend(base + c for c in cuts)
        self.starts = kept
        self.now = now
        self.latency = latency
        return vis


def chunks(wire: list[float], lo: int, latency: float) -> tuple[list[float], list[int]]:
    """USB chunks of ``wire[lo:]`` cut from ``lo``, byte by byte: ``(the time each byte is
    readable, the chunks' first indices)``. Any gaps."""
    n = len(wire)
    values: list[float] = []
    cuts = []
    chunk_start = lo
    for i in range(lo, n):
        full = i + 1 - chunk_start == USB_CHUNK
        if full or i + 1 == n or wire[i + 1] - wire[i] > latency:
            flush = wire[i] if full else wire[i] + latency
            values += [flush] * (i + 1 - chunk_start)
            cuts.append(chunk_start)
            chunk_start = i + 1
    return values, cuts


def even_chunks(
    wire: list[float], lo: int, m: int, latency: float
) -> tuple[list[float], list[int]]:
    """:func:`chunks` when no gap in ``wire[lo:]`` can exceed ``latency`` but the one
    between ``m - 1`` and ``m`` (where a burst joined the last chunk): whole chunks at a
    time instead of byte by byte."""
    n = len(wire)
    runs = [(lo, n)]
    if lo < m and wire[m] - wire[m - 1] > latency:
        runs = [(lo, m), (m, n)]
    values: list[float] = []
    cuts = []
    for a, b in runs:
        for c in range(a, b, USB_CHUNK):
            e = c + USB_CHUNK
            if e <= b:
                values += [wire[e - 1]] * USB_CHUNK
            else:
                e = b
                values += [wire[e - 1] + latency] * (e - c)
            cuts.append(c)
    return values, cuts


def full_visibility(wire: list[float], old: list[float], now: float, latency: float) -> list[float]:
    """When each unread byte (arriving at ``wire``) reaches the host through a USB adapter
    with latency timer ``latency`` > 0, given the times ``old`` computed before and the
    clock ``now``: the definition :meth:`UsbChunks.update` computes incrementally.

    Chunks are cut from the first byte: a chunk ends after 62 bytes (readable when its last
    byte arrives), at a gap longer than ``latency`` or at the last byte (readable
    ``latency`` after its last byte). A byte the host could already see stays visible.
    """
    vis = [0.0] * len(wire)
    chunk_start = 0
    for i in range(len(wire)):
        last = i + 1 == len(wire) or wire[i + 1] - wire[i] > latency
        if i + 1 - chunk_start == USB_CHUNK or last:
            flush = wire[i] if i + 1 - chunk_start == USB_CHUNK else wire[i] + latency
            for j in range(chunk_start, i + 1):
                vis[j] = flush
            chunk_start = i + 1
    for j in range(min(len(old), len(vis))):
        if old[j] <= now and wire[j] <= old[j]:
            vis[j] = min(vis[j], old[j])
    return vis
