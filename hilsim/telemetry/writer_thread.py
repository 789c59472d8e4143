"""The writer thread's half of :class:`~hilsim.telemetry.writer.TelemetryWriter`.

The loop's thread only leaves work where this half takes it: rows in the ring
(:mod:`hilsim.telemetry.ring`); events, flush requests and the stop in the inbox. Everything
that touches the disk runs here, on the writer thread: the rows handed to the sink in the
loop's free time, ``events.jsonl``, the flushes and fsyncs, and the end of the record; and when
the disk fails, what was not written is sorted out here for the end of the record. The
protocol between the two halves is described in docs/telemetry.md.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time
import traceback
from typing import Any, TextIO

from drivers.clock import Slack
from hilsim.telemetry.end_record import EndRecord
from hilsim.telemetry.format import TelemetryFormat, to_json
from hilsim.telemetry.ring import TickRing
from hilsim.telemetry.rotation import PartBook
from hilsim.telemetry.stats import RunStats

_yield_gil = getattr(os, "sched_yield", lambda: time.sleep(0))
#: a chunk is started only with at least this much of the loop's free time left
_CHUNK_BUDGET_S = 150e-6
#: how long the writer formats without waiting for the loop's free time once it has had none
#: long enough for a chunk for a while (see _drain_rows)
_BURST_S = 5e-3
_monotonic = time.monotonic
#: while the loop's free time has no end (a virtual-time show, the drain at the end) a chunk
#: is this many of a sink's chunks: the same rows with fewer turns of the loop below and of
#: the interpreter lock
_FREE_CHUNKS = 16
_UNBOUNDED = float("inf")

#: The inbox carries ``(event, fsync)`` tuples, the ``threading.Event`` of a flush() waiting
#: for the disk, _WAKE (drain the ring now: a blocked record() waits for space) and _STOP
#: (finish: the last rows, events and fsync, then the end of the record).
_STOP = object()
_WAKE = object()


class WriterThreadSide:
    """The writer thread's half of :class:`~hilsim.telemetry.writer.TelemetryWriter` (its base).

    :meth:`__init__` sets up this half's state: its files (opened by the loop's side's
    constructor, so a directory that cannot be written is the caller's error), its counters, the
    inbox it reads and the two events the loop waits on (``_rows_done``, ``_space``). Once the
    thread runs, only it writes that state, but the loop puts into the inbox and clears
    ``_space``; the loop reads ``_failed``, ``_error`` and ``error_traceback`` (set when the
    thread dies), ``rows_written`` and ``_events_got``. The annotations below are the loop's
    side's state that this half reads; it writes only ``events_dropped``, at the very end (the
    events the end of the record could not write).
    """

    flush_interval_s: float
    fsync_interval_s: float
    queue_size: int
    overflow: str
    format: TelemetryFormat
    format_reason: str
    stats: RunStats
    end: EndRecord
    slack: Slack
    rows_dropped: int
    events_dropped: int
    _last_dropped_tick: int | None
    _ring: TickRing
    book: PartBook | None
    runs_removed: dict[str, Any] | None
    _poll_s: float
    _chunk_rows: int

    def __init__(self) -> None:
        # writer-side counters (written only by the writer thread)
        self.rows_written = 0
        self._events_got = 0
        self._dropped_reported = 0
        # shared state
        self._failed = False
        self._error: BaseException | None = None
        #: the writer thread's traceback when it died (also in summary.json), else None
        self.error_traceback: str | None = None
        self._unwritten: list[dict[str, Any]] = []  # the batch of events being written
        # events in the file's buffer since its last flush (with their bytes), bytes flushed
        self._unflushed: list[tuple[dict[str, Any], int]] = []
        self._events_flushed = 0
        self._rows_done = threading.Event()  # finish() is done, or the writer died
        self._inbox: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._space = threading.Event()
        self._sink: Any = None
        self._events: TextIO | None = None

    @property
    def rows_recorded(self) -> int:
        """Rows accepted by :meth:`record` (queued; written or about to be)."""
        return self._ring.head

    def _run(self) -> None:
        try:
            self._write_rows()
        except BaseException as exc:
            self._died(exc)
        self._rows_done.set()
        tb = self.error_traceback
        text = None if tb is None else f"telemetry writer: {self._error!r}\n\n{tb}"
        self.end.write(self._leftovers, self._summary_for, text)

    def _write_rows(self) -> None:
        """Rows, events, flushes and fsyncs until close; raises when the disk fails."""
        last_flush = last_fsync = _monotonic()
        left_behind = False
        while True:
            try:  # rows left behind for want of free time: straight back after the events
                items = [self._inbox.get(timeout=0.0 if left_behind else self._poll_s)]
            except queue.Empty:
                items = []
            with contextlib.suppress(queue.Empty):
                while True:
                    items.append(self._inbox.get_nowait())
            stop = _STOP in items
            waiters = [item for item in items if isinstance(item, threading.Event)]
            batch = [item for item in items if isinstance(item, tuple)]
            self._unwritten = [ev for ev, _ in batch]  # kept for the end if the disk fails
            sync = stop or bool(waiters) or any(fsync for _, fsync in batch)
            left_behind = self._drain_rows()
            self._write_events(self._unwritten)
            self._report_drops()
            if self.book is not None and self.book.notes:  # the parts removed under a cap
                self._write_events(self.book.take_notes())
            if sync and not left_behind:  # (rows waiting for free time: the fsync first)
                left_behind = self._drain_rows()  # rows handed over during the events
            now = _monotonic()
            if now - last_fsync >= self.fsync_interval_s:
                sync = True  # a power cut loses at most this much
            if sync or now - last_flush >= self.flush_interval_s:
                self._flush_files(fsync=sync)
                last_flush = now
                if sync:
                    last_fsync = now
            for w in waiters:
                w.set()
            if stop:
                self._finish()
                return

    def _died(self, exc: BaseException) -> None:
        """The disk failed: the loop sees it at its next record(); the events not written are
        kept for the end of the record; anyone waiting in flush() is woken."""
        self._error = exc
        self._failed = True  # first: the loop must see the death at its next record()
        self._space.set()
        self.error_traceback = traceback.format_exc()
        older = self._events_not_on_disk() + self._unwritten
        with contextlib.suppress(queue.Empty):
            while True:
                item = self._inbox.get_nowait()
                if isinstance(item, tuple):
                    older.append(item[0])
                elif isinstance(item, threading.Event):
                    item.set()
        self.end.events[:0] = older

    def _drain_rows(self) -> bool:
        """Hand the ring's rows to the sink; True if some were left waiting for free time."""
        ring, sink = self._ring, self._sink
        if sink is None:  # summary-only: no rows
            return False
        slack = self.slack
        bursts = sink.bursts
        napping_since = None  # the first of the naps since the last chunk
        burst_until = -1.0  # chunks without waiting for free time until then
        while ring.pending() > 0 or sink.busy():
            # Format only in the loop's free time (see ``slack``), and never start a chunk that
            # could still be running when the loop wakes: nap past its deadline instead. But
            # for a sink whose work is cheap (``bursts``: Parquet), not for ever: when the loop
            # has had no free time long enough for a chunk for _poll_s (a fast rig whose bus
            # takes most of each tick), a burst of chunks (_BURST_S, the GIL yielded between
            # them) keeps the ring from filling and losing rows. A CSV sink waits, and drops
            # rows (counted and reported) rather than make the loop late.
            if _monotonic() < burst_until:
                pass
            elif not slack.wait(self._poll_s):
                if bursts:  # no free time for a while (else one chunk anyway, as ever)
                    burst_until = _monotonic() + _BURST_S
            elif (left := slack.remaining()) < _CHUNK_BUDGET_S:
                now = _monotonic()
                if napping_since is None:
                    napping_since = now
                if now - napping_since < self._poll_s:
                    time.sleep(max(left, 0.0) + _CHUNK_BUDGET_S)
                    continue
                if not bursts:  # back to _run for events, flushes and drop reports
                    return True
                burst_until = now + _BURST_S  # only short free times for a while
            napping_since = None
            if sink.busy():  # a step of the work on rows already taken (Parquet's encoding)
                sink.work()
            else:
                n = self._chunk_rows
                if slack.until == _UNBOUNDED and self.book is None:
                    n *= _FREE_CHUNKS  # no tick to be late for (virtual time, the end's drain)
                rows = sink.take(ring, n)  # slots are free once copied out
                if self.overflow == "block":
                    self._space.set()
                self.rows_written += sink.put(rows)
            _yield_gil()  # let the loop thread have the GIL between chunks
        return False

    def _write_events(self, evs: list[dict[str, Any]]) -> None:
        """Write ``evs`` in order; those not written when the disk fails stay in the list."""
        assert self._events is not None
        self._unwritten = evs
        while evs:
            line = to_json(evs[0]) + "\n"
            self._events.write(line)
            self._unflushed.append((evs[0], len(line.encode("utf-8"))))
            self._events_got += 1
            evs.pop(0)

    def _events_not_on_disk(self) -> list[dict[str, Any]]:
        """After a death: the events in the file's buffer that did not reach the disk whole
        (what did is told by the file's size). The buffer is dropped with its descriptor:
        closing it would write part of them again, or take the reserve's space."""
        f, self._events = self._events, None
        if f is None or not self._unflushed:
            self._events = f
            return []
        try:
            on_disk = os.fstat(f.fileno()).st_size - self._events_flushed
        except (OSError, ValueError):
            on_disk = 0
        lost: list[dict[str, Any]] = []
        for ev, n in self._unflushed:
            if on_disk >= n and not lost:
                on_disk -= n
            else:
                lost.append(ev)
        for close in (getattr(getattr(f, "buffer", None), "raw", f).close, f.close):
            with contextlib.suppress(Exception):
                close()
        return lost

    def _report_drops(self) -> None:
        dropped = self.rows_dropped
        if dropped != self._dropped_reported:
            ev = {
                "tick": self._last_dropped_tick,
                "t": None,
                "wall": time.time(),
                "kind": "telemetry_dropped",
                "message": f"telemetry queue full (a stalled disk? no CPU for the writer?): "
                f"{dropped - self._dropped_reported} rows dropped, {dropped} in total",
                "rows": dropped - self._dropped_reported,
                "total": dropped,
            }
            self._dropped_reported = dropped
            self._write_events([ev])

    def _flush_files(self, *, fsync: bool) -> None:
        if self._sink is not None:
            self.rows_written += self._sink.flush(fsync)
        f = self._events
        if f is not None:
            f.flush()
            self._events_flushed += sum(n for _, n in self._unflushed)
            self._unflushed.clear()
            if fsync:
                os.fsync(f.fileno())

    def _finish(self) -> None:
        self._drain_rows()
        items = []
        with contextlib.suppress(queue.Empty):
            while True:
                items.append(self._inbox.get_nowait())
        self._write_events([item[0] for item in items if isinstance(item, tuple)])
        self._report_drops()
        self._flush_files(fsync=True)
        if self.book is not None and self.book.notes:
            self._write_events(self.book.take_notes())
            self._flush_files(fsync=True)
        if self._sink is not None:
            self._sink.close()  # (gzip's trailer: a failure here is the writer's too)
            self._sink = None
        for item in items:
            if isinstance(item, threading.Event):
                item.set()

    def _telemetry_summary(self) -> dict[str, Any]:
        recorded = self.rows_recorded
        return {
            "rows_recorded": recorded,
            "rows_written": self.rows_written,
            "rows_dropped": self.rows_dropped,
            "rows_lost": recorded - self.rows_written,
            "events_dropped": self.events_dropped,
            "queue_size": self.queue_size,
            "overflow": self.overflow,
            "format": str(self.format),
            "format_reason": self.format_reason,
            "error": None if self._error is None else repr(self._error),
            "error_traceback": self.error_traceback,
            "rotation": None if self.book is None else self.book.summary(),
            "runs_removed": self.runs_removed,
        }

    def _leftovers(self) -> list[dict[str, Any]]:
        """At the end: the files closed (after a death, what their buffers hold goes now, if it
        fits; the rows counted on the disk), and the events queued as the writer died."""
        sink = self._sink
        self._close_files()
        if self._failed and sink is not None:  # what its buffer held may not be there
            with contextlib.suppress(OSError):
                on_disk = sink.rows_on_disk()
                self.rows_written = self.rows_written if on_disk is None else on_disk
        evs = []
        with contextlib.suppress(queue.Empty):
            while True:
                item = self._inbox.get_nowait()
                if isinstance(item, tuple):
                    evs.append(item[0])
        return evs

    def _summary_for(self, outcome: dict[str, Any], events_lost: int) -> dict[str, Any]:
        self.events_dropped += events_lost
        summary = self.stats.summary()
        summary.update(outcome)
        summary["telemetry"] = self._telemetry_summary()
        return summary

    def _close_files(self) -> None:
        for name in ("_sink", "_events"):
            f = getattr(self, name, None)
            setattr(self, name, None)
            if f is not None:
                with contextlib.suppress(OSError, ValueError):
                    f.close()
