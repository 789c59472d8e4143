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
     │                              close; raised by the next record()/flush()/close(); __cause__
     │                              holds the original error
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
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
import time
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TextIO

import numpy as np

from drivers.clock import Slack
from hilsim.telemetry.format import (
    CONFIG_NAME,
    EVENTS_JSONL,
    SUMMARY_JSON,
    TelemetryError,
    TickRecord,
    check_joint_names,
    choose_format,
    csv_columns,
)
from hilsim.telemetry.ring import TickRing
from hilsim.telemetry.sinks import fsync_dir, open_sink
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


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, set | frozenset | tuple):
        return list(obj)
    return repr(obj)


def _dumps(obj: Any, **kw: Any) -> str:
    return json.dumps(obj, default=_json_default, ensure_ascii=False, **kw)


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
    copied to ``run_dir/config_name``.

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
        self._summary: dict[str, Any] = {}
        self._written_summary: dict[str, Any] | None = None
        self._finished = False
        self._failure_handled = False
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
            if config_text is not None:
                (self.run_dir / config_name).write_text(config_text, encoding="utf-8")
        except BaseException:
            self._close_files()
            raise
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
        ``os.fsync``-s both files right away. Events of
        kind ``"fault"`` also go into the summary's ``faults`` list. Never blocks and never raises
        for a dead writer (it may be called while handling a fault or a signal); returns False if
        the event was not queued (writer closed or failed, or more than ``max_pending_events``
        waiting), which is counted in ``events_dropped``.
        """
        if kind == "fault":
            self.stats.fault(kind, message, tick, t, **fields)
        if self._failed or self._close_requested:
            self.events_dropped += 1
            return False
        if self._events_put - self._events_got >= self.max_pending_events:
            self.events_dropped += 1
            return False
        ev = {"tick": tick, "t": t, "wall": time.time(), "kind": str(kind), "message": str(message)}
        if fields:
            ev.update(fields)
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
        if self._finished or self._close_requested:
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
                if not self._thread.is_alive() or (
                    deadline is not None and _monotonic() > deadline
                ):
                    break
        finally:
            slack.until = until
            if not was_set:
                slack.clear()
        if self._failed:
            self._raise_not_open()
        return done.is_set()

    def close(
        self, summary: Mapping[str, Any] | None = None, *, timeout_s: float = 10.0
    ) -> dict[str, Any]:
        """Drain the ring, fsync, write ``summary.json``; return the summary written.

        The summary is :meth:`RunStats.summary` of :attr:`stats`, updated with ``summary``'s keys
        (the caller's win: e.g. ``exit_code``, ``exit_reason``, ``duration_s``), plus a
        ``"telemetry"`` entry (rows recorded/written/dropped/lost, events dropped, error).
        Idempotent: the first call's summary wins, later calls wait for the same completion and
        return the same dict. Safe from a signal handler and after a writer failure (no lock;
        joins the thread). Raises :class:`WriterFailedError` (every call) if the writer died
        (summary.json is still written when the disk allows) or did not finish within
        ``timeout_s`` (disk stalled).
        """
        if not self._close_requested:
            self._summary = dict(summary) if summary is not None else {}
            self._publish_pending()
            self._close_requested = True
            self.slack.until = float("inf")  # the loop is done: drain at full speed
            self.slack.set()
            self._inbox.put(_STOP)
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise WriterFailedError(
                f"telemetry writer did not finish within {timeout_s} s (disk stalled?); "
                f"{self._ring.pending()} rows still queued"
            )
        if self._failed:
            self._handle_failure()
            raise WriterFailedError(f"telemetry writer failed: {self._error!r}") from self._error
        return self._written_summary if self._written_summary is not None else {}

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
                left_behind = self._drain_rows()
                sync = stop
                waiters = []
                for item in items:
                    if isinstance(item, tuple):
                        ev, fsync = item
                        self._write_event(ev)
                        sync = sync or fsync
                    elif isinstance(item, threading.Event):
                        waiters.append(item)
                        sync = True
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
        except BaseException as exc:
            self._error = exc
            self._failed = True  # first: the loop must see the death at its next record()
            self._space.set()
            self.error_traceback = traceback.format_exc()  # read after join() (close)
            # wake anyone waiting in flush()
            with contextlib.suppress(queue.Empty):
                while True:
                    item = self._inbox.get_nowait()
                    if isinstance(item, threading.Event):
                        item.set()

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

    def _write_event(self, ev: dict[str, Any]) -> None:
        assert self._events is not None
        self._events_got += 1
        self._events.write(_dumps(ev) + "\n")

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
            assert self._events is not None
            self._events.write(_dumps(ev) + "\n")

    def _flush_files(self, *, fsync: bool) -> None:
        if self._sink is not None:
            self.rows_written += self._sink.flush(fsync)
        for f in (self._events,):
            if f is not None:
                f.flush()
                if fsync:
                    os.fsync(f.fileno())

    def _finish(self) -> None:
        self._drain_rows()
        with contextlib.suppress(queue.Empty):
            while True:
                item = self._inbox.get_nowait()
                if isinstance(item, tuple):
                    self._write_event(item[0])
                elif isinstance(item, threading.Event):
                    item.set()
        self._report_drops()
        self._flush_files(fsync=True)
        self._close_files()
        self._write_summary()
        self._finished = True

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

    def _write_summary(self) -> None:
        summary = self.stats.summary()
        summary.update(self._summary)
        summary["telemetry"] = self._telemetry_summary()
        path = self.run_dir / SUMMARY_JSON
        tmp = path.with_name(path.name + ".tmp")
        try:
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(_dumps(summary, indent=2) + "\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):  # a full disk: leave no empty half-file
                tmp.unlink()
            raise
        fsync_dir(self.run_dir)
        self._written_summary = summary

    def _close_files(self) -> None:
        for name in ("_sink", "_events"):
            f = getattr(self, name, None)
            setattr(self, name, None)
            if f is not None:
                with contextlib.suppress(OSError, ValueError):
                    f.close()

    def _handle_failure(self) -> None:
        """After the writer thread died: best-effort flush/close and a summary, once."""
        if self._failure_handled:
            return
        self._failure_handled = True
        with contextlib.suppress(Exception):
            self._flush_files(fsync=True)
        self._close_files()
        with contextlib.suppress(Exception):
            self._write_summary()
