"""Run telemetry writer: a row per tick, events and a summary, written by a background thread.

The run directory's files, CSV columns and number formats are described in
:mod:`hilsim.telemetry.format`; the rows go to a sink of the run's format
(:mod:`hilsim.telemetry.sinks`: CSV, csv.gz, Parquet); the statistics behind the summary are in
:mod:`hilsim.telemetry.stats`; :func:`hilsim.telemetry.reader.read_run` reads a run back.

The loop's thread only copies each tick into a preallocated ring and the run statistics
(:meth:`TelemetryWriter.record`: no disk, no lock), so a stalled or full disk never makes a
tick late. The writer thread (:mod:`hilsim.telemetry.writer_thread`, the class's other half)
formats and writes the rows in the loop's free time, writes the events, flushes and fsyncs,
and writes the end of the record into space set aside at the start
(:mod:`hilsim.telemetry.end_record`): a full disk keeps its fault record and its summary. The
real-time contract, what a full ring does (drop or block) and how the loop uses the writer
are in docs/telemetry.md.

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
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from drivers.clock import Slack
from hilsim.telemetry.end_record import EndRecord
from hilsim.telemetry.format import (
    CONFIG_NAME,
    EVENTS_JSONL,
    TelemetryError,
    TelemetryFormat,
    TickRecord,
    check_joint_names,
    choose_format,
    csv_columns,
)
from hilsim.telemetry.ring import TickRing
from hilsim.telemetry.rotation import PartBook
from hilsim.telemetry.sinks import open_sink
from hilsim.telemetry.stats import RunStats
from hilsim.telemetry.writer_thread import _STOP, _WAKE, WriterThreadSide

#: event kinds that are fsync-ed by default (``event(..., fsync=None)``)
FSYNC_KINDS: frozenset[str] = frozenset({"start", "fault", "signal", "stop", "exit_policy"})

_monotonic = time.monotonic


class WriterFailedError(TelemetryError):
    """The writer thread died or could not finish; rows may be lost (see ``__cause__``)."""


class TelemetryWriter(WriterThreadSide):
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
    copied to ``run_dir/config_name``. ``max_bytes``/``max_age_s`` cap the rows: they are
    written in parts, the oldest removed first (:mod:`hilsim.telemetry.rotation`). Format
    ``none`` (and ``off``) keeps no rows: :meth:`record` only feeds :attr:`stats`.
    Space for the end of the record is set aside last
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
        max_bytes: int | None = None,
        max_age_s: float | None = None,
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
        self._rows_off = self.format in (TelemetryFormat.NONE, TelemetryFormat.OFF)
        self.book: PartBook | None = None
        #: the runs removed under the runs root's caps as this run started (the summary's
        #: ``telemetry.runs_removed``), set by the show; None: no such cap
        self.runs_removed: dict[str, Any] | None = None
        super().__init__()  # the writer thread's state (hilsim.telemetry.writer_thread)
        #: Rows are formatted only while this is set. A real-time loop passes it to
        #: ``MonotonicClock.wait_until(t, idle=...)``: set while the loop sleeps, clear while a
        #: tick runs, so the writer never holds the GIL in the middle of a tick.
        self.slack = Slack()
        self.slack.set()

        self.run_dir.mkdir(parents=True, exist_ok=True)
        try:
            if self.format in (TelemetryFormat.NONE, TelemetryFormat.OFF):
                self._sink, self._chunk_rows = None, 1  # summary-only: no rows kept
            else:
                capped = max_bytes is not None or max_age_s is not None
                self.book = PartBook(max_bytes, max_age_s) if capped else None
                self._sink = open_sink(self.format, self.run_dir, names, self._open, self.book)
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
        if self._rows_off:
            return True  # summary-only: the statistics are the record
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
        return False if self._rows_off else self._ring.amend(rec)

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

    def _open(self, path: Path, mode: str) -> Any:
        """Open one output file (a hook: tests wrap it to simulate a stalled or full disk)."""
        if "b" in mode:
            return open(path, mode, buffering=1 << 16)
        return open(path, mode, encoding="utf-8", newline="", buffering=1 << 16)
