"""Run telemetry writer: a row per tick, events and a summary, written by a background thread.

The run directory's files, CSV columns and number formats are described in
:mod:`hilsim.telemetry.format`; the rows go to a sink of the run's format
(:mod:`hilsim.telemetry.sinks`: CSV, csv.gz, Parquet); the statistics behind the summary are in
:mod:`hilsim.telemetry.stats`; :func:`hilsim.telemetry.reader.read_run` reads a run back.

**Real-time contract.** :meth:`TelemetryWriter.record` copies the tick's numbers into a slot of a
preallocated ring (a float64 array, one row per slot) and into the run statistics
(:class:`~hilsim.telemetry.stats.RunStats`, preallocated chunks), and returns; it never touches the
disk, takes no lock and allocates nothing but a row view. A row is handed to the writer thread when
the *next* row is recorded (or at :meth:`~TelemetryWriter.flush`/:meth:`~TelemetryWriter.close`), so
values known only at the end of the tick (overrun, the telemetry stage's own time) can still be
filled in with :meth:`~TelemetryWriter.amend`. The writer thread drains the ring every few tens of
ms, hands rows to the sink in small chunks (yielding the GIL between chunks: one CSV row, ~100 µs at
16 joints, or 256 Parquet rows, numpy and pyarrow calls of tens of µs; gzip and Parquet's encoder
run without the GIL), writes them, flushes every ``flush_interval_s``, and ``os.fsync``-s every
``fsync_interval_s``, on start, fault, signal and exit-policy events and at close (a power cut loses
at most the last ``fsync_interval_s``; a Parquet part is written at each fsync). The ring is
single-producer/single-consumer: the loop only advances the head, the writer only the tail;
CPython's GIL orders the row stores before the head store. When the ring is full (disk stalled) the
row is dropped and counted (``overflow="drop"``, the real-time default) or record waits for space
(``overflow="block"``, for virtual-time runs that must be lossless). Dropped rows are reported as an
event, in the summary and by :func:`~hilsim.telemetry.reader.read_run`; the statistics still cover
them.

Exceptions::

    TelemetryError                  (hilsim.telemetry.format) base of the writer's and reader's
     │                              errors
     ├── WriterFailedError          the writer thread died (disk full, I/O error) or stalled at
     │                              close; raised by the next record()/flush()/close(), and by
     │                              write_summary() when summary.json could not be written;
     │                              __cause__ holds the original error
     ├── NotARunError               (reader) read_run: no rows in the directory (telemetry.csv,
     │                              .csv.gz or .parquet/; also a FileNotFoundError)
     └── RunFormatError             (reader) read_run: the rows are not telemetry, or Parquet
                                    without pyarrow (also a ValueError)

Loop usage::

    tel = TelemetryWriter(run_dir, joint_names, servo_ids=ids, config_text=rig_text)
    tel.event("start", "run started", 0, 0.0, rate_hz=rate)
    rec = TickRecord(target=u, sim_x=x, sim_v=v, cmd=cmd, present=present, status=status)
    every tick k:
        rec.tick, rec.t_sched, rec.t_actual, rec.t_bus_us, ... = ...   # in place
        tel.record(rec)
        ...                                     # the rest of the tick
        rec.t_telemetry_us, rec.overrun = dt_us, late
        tel.amend(rec)                          # optional, before the next record
    on a fault:   tel.event("fault", msg, k, t, joint="jaw")   # fsync-ed; listed in the summary
    at the end:   tel.stats.set_safety_counts(...)             # the safety filter's counters
                  summary = tel.close({"exit_code": 0, "exit_reason": "end of show"})
    or, when the outcome depends on the record:   error = tel.finish()   # the rows' end
                  ... the outcome, from error ...;  summary = tel.write_summary(outcome)

**The end of the record** (events logged after :meth:`~TelemetryWriter.finish` or after the
writer died, the writer's traceback, ``summary.json``) is written once, last, on the writer
thread, into space set aside at the start (:mod:`hilsim.telemetry.end_record`): a full disk
keeps its fault record and its summary.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TextIO

from drivers.clock import Slack
from hilsim.telemetry.end_record import EndRecord
from hilsim.telemetry.format import (
    CONFIG_NAME,
    EVENTS_JSONL,
    TelemetryError,
    TickRecord,
    check_joint_names,
    choose_format,
    csv_columns,
    to_json,
)
from hilsim.telemetry.ring import TickRing
from hilsim.telemetry.sinks import open_sink
from hilsim.telemetry.stats import RunStats

#: event kinds that are fsync-ed by default (``event(..., fsync=None)``)
FSYNC_KINDS: frozenset[str] = frozenset({"start", "fault", "signal", "stop", "exit_policy"})

_yield_gil = getattr(os, "sched_yield", lambda: time.sleep(0))
#: a chunk is started only with at least this much of the loop's free time left
_CHUNK_BUDGET_S = 150e-6
#: how long the writer formats without waiting for the loop's free time once it has had none
#: long enough for a chunk for a while (see _drain_rows)
_BURST_S = 5e-3
_monotonic = time.monotonic


class WriterFailedError(TelemetryError):
    """The writer thread died or could not finish; rows may be lost (see ``__cause__``)."""


_STOP = object()
_WAKE = object()


class TelemetryWriter:
    """Writes one run directory from a background thread; the loop only calls cheap methods.

    ``run_dir`` is created if needed; rows already in it are an error (a run directory holds one
    run). ``format`` is a :class:`~hilsim.telemetry.format.TelemetryFormat` value; ``auto`` is
    resolved with ``rate_hz`` (:func:`~hilsim.telemetry.format.choose_format`; the choice and why
    are :attr:`format` and :attr:`format_reason`, also in the summary; a ``parquet`` without
    pyarrow is a ``ValueError``). ``joint_names`` become column suffixes (no commas, quotes or
    newlines); ``servo_ids`` (same order) name the servos in the summary's ``comm_errors``.
    ``queue_size`` ring rows absorb a disk stall of ``queue_size / rate`` seconds (16384 rows:
    16 s at 1 kHz; ``8 * (12 + 6 * n_joints)`` bytes a row, 7.9 MB for 8 joints). ``overflow``
    picks what a full ring does: ``"drop"`` (count the row, return False: never blocks) or
    ``"block"`` (wait for the writer: lossless, for virtual-time runs). ``config_text`` is
    copied to ``run_dir/config_name``. Space for the end of the record is set aside last
    (``end.reserve``; if the disk has none, its ``error`` says why and the run goes on).

    :attr:`stats` (a :class:`RunStats`) is fed by :meth:`record`, :meth:`amend` and :meth:`event`
    (faults); :meth:`close` turns it into the summary.

    Thread safety: :meth:`record`, :meth:`amend` and :meth:`flush` from the loop thread only.
    :meth:`event` and :meth:`close` may also be called from a signal handler: neither takes a lock
    that the interrupted code could hold (``queue.SimpleQueue.put`` is reentrant; close waits by
    joining the thread), and a row interrupted half-written is never handed to the writer.
    """

    def __init__(
        self,
        run_dir: str | os.PathLike[str],
        joint_names: Sequence[str],
        *,
        servo_ids: Sequence[Any] | None = None,
        flush_interval_s: float = 0.5,
        fsync_interval_s: float = 2.0,
        queue_size: int = 16384,
        overflow: Literal["drop", "block"] = "drop",
        config_text: str | None = None,
        config_name: str = CONFIG_NAME,
        max_pending_events: int = 10_000,
        format: str = "csv",
        rate_hz: float | None = None,
    ) -> None:
        names = check_joint_names(joint_names)
        self.format, self.format_reason = choose_format(format, rate_hz, len(names))
        if not flush_interval_s >= 0.0:
            raise ValueError(f"flush_interval_s must be >= 0, got {flush_interval_s!r}")
        if int(queue_size) < 2:
            raise ValueError(f"queue_size must be >= 2, got {queue_size!r}")
        if overflow not in ("drop", "block"):
            raise ValueError(f"overflow must be 'drop' or 'block', got {overflow!r}")
        self.run_dir = Path(run_dir)
        self.joint_names = names
        self.columns: tuple[str, ...] = tuple(csv_columns(names))
        self.flush_interval_s = float(flush_interval_s)
        if not fsync_interval_s > 0.0:
            raise ValueError(f"fsync_interval_s must be > 0, got {fsync_interval_s!r}")
        self.fsync_interval_s = float(fsync_interval_s)
        self.queue_size = int(queue_size)
        self.overflow = overflow
        self.max_pending_events = int(max_pending_events)
        self.stats = RunStats(names, servo_ids=servo_ids)

        n = len(names)
        self._ncols = len(self.columns)
        self._ring = TickRing(self.queue_size, n, self._ncols)
        # drain often enough that formatting is spread thin; flush to the OS on its own interval
        self._poll_s = min(0.05, self.flush_interval_s) if self.flush_interval_s > 0 else 0.01

        # Loop-side state (written by the loop thread, or a signal handler on it); the ring's
        # cursor protocol is in hilsim.telemetry.ring.
        self.rows_dropped = 0
        self._last_dropped_tick: int | None = None
        self._events_put = 0
        self.events_dropped = 0
        self._close_requested = False
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
        #: Rows are formatted only while this is set. A real-time loop passes it to
        #: ``MonotonicClock.wait_until(t, idle=...)``: set while the loop sleeps, clear while a
        #: tick runs, so the writer never holds the GIL in the middle of a tick.
        self.slack = Slack()
        self.slack.set()

        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._sink: Any = None
        self._events: TextIO | None = None
        try:
            self._sink = open_sink(self.format, self.run_dir, names, self._open)
            self._chunk_rows = self._sink.chunk_rows
            self._events = self._open(self.run_dir / EVENTS_JSONL, "a")
            self._events_flushed = os.fstat(self._events.fileno()).st_size
            if config_text is not None:
                (self.run_dir / config_name).write_text(config_text, encoding="utf-8")
        except BaseException:
            self._close_files()
            raise
        #: the end of the record and the space set aside for it (``.reserve``)
        self.end = EndRecord(self.run_dir, len(names))
        self._thread = threading.Thread(target=self._run, name="telemetry-writer", daemon=True)
        self._thread.start()

    # ----------------------------------------------------------------- the loop's side

    def record(self, rec: TickRecord) -> bool:
        """Queue one tick's row; return True if queued, False if dropped (ring full, disk stalled).

        ``rec`` (:class:`~hilsim.telemetry.format.TickRecord`) is copied, so the loop reuses it
        and its buffers: arrays shaped ``(n_joints,)``; ``target``, ``sim_x``, ``cmd``,
        ``present`` in rad, ``sim_v`` in rad/s, ``present`` NaN where there was no valid read,
        ``status`` :class:`ReadStatus` codes; times in s since run start; stage times in µs
        (NaN if not known yet: see :meth:`amend`); ``comm_errors`` and ``skipped_ticks``
        cumulative; ``host_stall_us`` the host's own stall in this tick. Never blocks with
        ``overflow="drop"``; a dropped row still counts in :attr:`stats`.

        Raises :class:`WriterFailedError` if the writer thread has died, and
        :class:`TelemetryError` after :meth:`close`.
        """
        if self._failed or self._close_requested:
            self._raise_not_open()
        self.stats.add(rec)
        ring = self._ring
        full = ((ring.cursor + 1) >> 1) - ring.tail >= ring.size  # ring.full(), on every tick
        if full and not self._wait_for_space(rec.tick):
            ring.publish_pending()  # hand the previous row over; this one is gone
            return False
        ring.put(rec)
        return True

    def warm_up(self, rec: TickRecord, n: int) -> None:
        """Run :meth:`record`'s and :meth:`amend`'s books ``n`` times on scratch ones (run
        stats of ``n`` ticks, a two-row ring) before a real-time show (:mod:`hilsim.show.warm_up`):
        nothing is queued or counted."""
        stats, ring = (
            RunStats(self.joint_names, chunk_ticks=n),
            TickRing(2, len(self.joint_names), self._ncols),
        )
        for _ in range(n):
            stats.add(rec)
            ring.put(rec)
            stats.amend(rec)
            ring.amend(rec)

    def amend(self, rec: TickRecord) -> bool:
        """Write the late values of the last recorded tick (``rec.tick``): its stage times and
        overrun, known only after :meth:`record`.

        :attr:`stats` is always updated; the CSV row only until it is handed to the writer (at
        the next :meth:`record`, :meth:`flush`, :meth:`close` or fsync-ed :meth:`event`): the
        return value says whether it was (False also when the row was dropped). Raises
        ``ValueError`` for any tick but the last recorded one.
        """
        self.stats.amend(rec)
        return self._ring.amend(rec)

    def event(
        self,
        kind: str,
        message: str = "",
        tick: int | None = None,
        t: float | None = None,
        *,
        fsync: bool | None = None,
        **fields: Any,
    ) -> bool:
        """Queue one ``events.jsonl`` line: ``{"tick", "t", "wall", "kind", "message", **fields}``.

        ``t`` is clock time in s since run start; ``wall`` (Unix time) is added here. With
        ``fsync=True`` (default: ``kind in FSYNC_KINDS``, i.e. faults, signals, stop) the writer
        drains pending rows (including the last recorded one) and events, flushes and
        ``os.fsync``-s both files right away. Events of kind ``"fault"`` also go into the
        summary's ``faults`` list. After :meth:`finish`, or once the writer has died, events are
        kept for the end of the record (a hundred at most). Never blocks and never raises for a
        dead writer (it may be called while handling a fault or a signal); returns False if the
        event was not kept (the end of the record under way, or more than
        ``max_pending_events`` waiting), which is counted in ``events_dropped``.
        """
        if kind == "fault":
            self.stats.fault(kind, message, tick, t, **fields)
        ev = {"tick": tick, "t": t, "wall": time.time(), "kind": str(kind), "message": str(message)}
        if fields:
            ev.update(fields)
        if self._failed or self._close_requested:
            if self.end.keep(ev):
                return True
            self.events_dropped += 1
            return False
        if self._events_put - self._events_got >= self.max_pending_events:
            self.events_dropped += 1
            return False
        sync = kind in FSYNC_KINDS if fsync is None else bool(fsync)
        if sync:
            self._publish_pending()  # the last complete row belongs in what gets fsync-ed
        self._events_put += 1
        self._inbox.put((ev, sync))
        return True

    def flush(self, timeout_s: float | None = 10.0) -> bool:
        """Hand over the pending row, write everything queued, flush and fsync; wait for it.

        Blocks (never call it inside the tick; loop thread only). Returns False on timeout.
        Raises :class:`WriterFailedError` if the writer thread has died.
        """
        if self._failed:
            self._raise_not_open()
        if self._close_requested:
            return True
        self._publish_pending()
        done = threading.Event()
        slack, was_set, until = self.slack, self.slack.is_set(), self.slack.until
        slack.until = float("inf")  # the loop waits here: free time for all of it
        slack.set()
        self._inbox.put(done)
        deadline = None if timeout_s is None else _monotonic() + timeout_s
        try:
            while not done.wait(0.05):
                if self._rows_done.is_set() or (deadline is not None and _monotonic() > deadline):
                    break
        finally:
            slack.until = until
            if not was_set:
                slack.clear()
        if self._failed:
            self._raise_not_open()
        return done.is_set()

    def finish(self, timeout_s: float = 10.0) -> BaseException | None:
        """The end of the rows: hand over the pending row, drain the ring, write the queued
        events, flush and fsync, close the rows file; wait up to ``timeout_s``.

        Returns None when everything recorded is on the disk, else why not: the writer's error
        (a full disk, an I/O error: :attr:`error`), or a :class:`WriterFailedError` when it did
        not finish in time (disk stalled). Never raises; idempotent. Events logged from now on
        go into the end of the record (:meth:`write_summary`), so the outcome can be decided
        from this result before the summary says it.
        """
        if not self._close_requested:
            self._publish_pending()
            self._close_requested = True
            self.slack.until = float("inf")  # the loop is done: drain at full speed
            self.slack.set()
            self._inbox.put(_STOP)
        if not self._rows_done.wait(timeout_s):
            return WriterFailedError(
                f"telemetry writer did not finish within {timeout_s} s (disk stalled?); "
                f"{self._ring.pending()} rows still queued"
            )
        return self._error

    def write_summary(
        self, summary: Mapping[str, Any] | None = None, *, timeout_s: float = 10.0
    ) -> dict[str, Any]:
        """The end of the record, once (after :meth:`finish`, which it calls if need be): the
        events kept for it, the writer's traceback (``telemetry_error.txt``, if it died), then
        ``summary.json``; return the summary written.

        The summary is :meth:`RunStats.summary` of :attr:`stats`, updated with ``summary``'s
        keys (the caller's win: e.g. ``exit_code``, ``exit_reason``), plus a ``"telemetry"``
        entry (rows recorded/written/dropped/lost, events dropped, error). The first call's
        summary wins; later calls return the same dict. Raises :class:`WriterFailedError` when
        summary.json could not be written (``__cause__``: why; there is then no summary.json)
        or not within ``timeout_s``.
        """
        end = self.end
        if not self._close_requested:
            self.finish(timeout_s)
        end.request(summary)
        if not end.done.wait(timeout_s):
            raise WriterFailedError(f"not written within {timeout_s} s (disk stalled?)")
        if end.error is not None:
            raise WriterFailedError(f"summary.json not written: {end.error}") from end.error
        return end.summary if end.summary is not None else {}

    def close(
        self, summary: Mapping[str, Any] | None = None, *, timeout_s: float = 10.0
    ) -> dict[str, Any]:
        """:meth:`finish`, then :meth:`write_summary` with ``summary``; return the summary
        written. Idempotent: the first call's summary wins, later calls wait for the same
        completion and return the same dict. Safe from a signal handler and after a writer
        failure (no lock). Raises :class:`WriterFailedError` (every call) if the writer died
        (summary.json is still written when the disk allows), did not finish within
        ``timeout_s`` (disk stalled), or summary.json could not be written.
        """
        error = self.finish(timeout_s)
        if not self._rows_done.is_set():
            assert error is not None
            raise error
        try:
            written = self.write_summary(summary, timeout_s=timeout_s)
        except WriterFailedError:
            if error is None:
                raise
            written = {}
        if error is not None:
            raise WriterFailedError(f"telemetry writer failed: {error!r}") from error
        return written

    def __enter__(self) -> TelemetryWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def failed(self) -> bool:
        """True once the writer thread has died; :attr:`error` holds why."""
        return self._failed

    @property
    def error(self) -> BaseException | None:
        return self._error

    @property
    def rows_recorded(self) -> int:
        """Rows accepted by :meth:`record` (queued; written or about to be)."""
        return self._ring.head

    def _publish_pending(self) -> None:
        self._ring.publish_pending()

    def _raise_not_open(self) -> None:
        if self._failed:
            raise WriterFailedError(f"telemetry writer failed: {self._error!r}") from self._error
        raise TelemetryError("telemetry writer is closed")

    def _wait_for_space(self, tick: int) -> bool:
        if self.overflow == "drop":
            self.rows_dropped += 1
            self._last_dropped_tick = tick
            return False
        ring = self._ring
        ring.publish_pending()  # hand the previous row over so the writer can drain it
        woke = False
        while ring.full():
            if self._failed:
                self._raise_not_open()
            self._space.clear()
            if not ring.full():
                break
            if not woke:
                self._inbox.put(_WAKE)
                woke = True
            self._space.wait(0.1)
        return True

    # ----------------------------------------------------------------- the writer thread

    def _open(self, path: Path, mode: str) -> Any:
        """Open one output file (a hook: tests wrap it to simulate a stalled or full disk)."""
        if "b" in mode:
            return open(path, mode, buffering=1 << 16)
        return open(path, mode, encoding="utf-8", newline="", buffering=1 << 16)

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
        assert self._sink is not None
        ring, sink = self._ring, self._sink
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
                rows = sink.take(ring, self._chunk_rows)  # slots are free once copied out
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
