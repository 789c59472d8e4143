"""Where the telemetry writer's rows go: one sink per format (:class:`~hilsim.telemetry.format.
TelemetryFormat`), all run on the writer thread.

=================  ==============================================================================
:class:`CsvSink`   ``telemetry.csv`` (exact ``%.17g`` text) or ``telemetry.csv.gz`` (the same
                   text through gzip level 1, a sync flush at every flush of the writer, so a crash
                   leaves everything up to the last flush decodable)
:class:`ParquetSink`  ``telemetry.parquet/part-NNNNN.parquet``: rows buffered between fsync points,
                   each part written whole (temporary name, fsync, rename), fixed-point integers,
                   DELTA_BINARY_PACKED, zstd (pyarrow, imported only here)
=================  ==============================================================================

A sink has ``chunk_rows`` (rows the writer takes from the ring between two GIL yields),
``bursts`` (whether the writer may work in bursts outside the loop's free time when that
never comes long enough: cheap per row, as Parquet; CSV formats every float under the
interpreter lock, and a burst of it would make a fast loop late), ``take(ring, n)``,
``put(rows) -> rows now written``, ``busy()`` and ``work()`` (work left on rows already put,
done a step of ~0.1 ms at a time in the loop's free time: Parquet's encoding),
``flush(fsync) -> rows now written``, ``close()`` and ``rows_on_disk()`` (after a failure: the
rows the disk holds, None if not known better than the count).
Errors (a full disk) propagate to the writer thread, whose failure path handles them.
"""

from __future__ import annotations

import contextlib
import gzip
import os
import time
from collections.abc import Callable, Generator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hilsim.telemetry.format import (
    JOINT_FIELDS,
    STAGES,
    TELEMETRY_CSV,
    TELEMETRY_CSV_GZ,
    TELEMETRY_PARQUET,
    TELEMETRY_PARTS,
    TelemetryFormat,
    csv_columns,
    parquet_columns,
)
from hilsim.telemetry.ring import TickRing
from hilsim.telemetry.rotation import Part, PartBook

Opener = Callable[[Path, str], Any]

_EXACT = "%.17g"  # round-trips every float64; also prints integral floats as integers
_MICROS = "%.3f"
_CHUNK_FLOATS = 128  # floats formatted between GIL yields: ~50 µs of work
_GZ_LEVEL = 1  # 2.7x smaller than the text at a tenth of the CPU of level 6 (measured)
_GZ_BATCH = 1 << 16  # text compressed in pieces of about this many bytes
_PARQUET_TAKE_ROWS = 256  # rows copied out of the ring per chunk (~220 kB at 16 joints)
_PARQUET_MAX_ROWS = 50_000  # a part is written at the latest after this many rows
_PREP_ROWS = 64  # rows of numpy work in one encoding step (~70 µs at 16 joints)
_ARROW_COLUMNS = 16  # columns handed to pyarrow in one encoding step (~90 µs)
_INT_LIMIT = float(2**62)  # larger magnitudes are stored as +-(2**63 - 1): +-inf
INT_INF = 2**63 - 1


def row_format(n: int) -> str:
    """The ``%`` format of one CSV row for ``n`` joints (format.py: the number formats)."""
    exact_block = [_EXACT] * n
    fields = [
        _EXACT,  # tick
        _EXACT,  # t_sched
        _EXACT,  # t_actual
        _MICROS,  # lateness_us
        *exact_block * len(JOINT_FIELDS),  # target, sim_x, sim_v, cmd, present, status
        *[_MICROS] * len(STAGES),
        _EXACT,  # overrun
        _EXACT,  # comm_errors
        _MICROS,  # host_stall_us
        _EXACT,  # skipped_ticks
    ]
    return ",".join(fields) + "\n"


def rows_path(run_dir: Path, fmt: TelemetryFormat, *, parts: bool = False) -> Path:
    """The file (or, for Parquet and CSV in ``parts``, directory) the rows in ``fmt`` go to."""
    if parts and fmt is not TelemetryFormat.PARQUET:
        return run_dir / TELEMETRY_PARTS
    names = {
        TelemetryFormat.CSV: TELEMETRY_CSV,
        TelemetryFormat.CSV_GZ: TELEMETRY_CSV_GZ,
        TelemetryFormat.PARQUET: TELEMETRY_PARQUET,
    }
    return run_dir / names[fmt]


def open_sink(
    fmt: TelemetryFormat,
    run_dir: Path,
    joint_names: Sequence[str],
    opener: Opener,
    book: PartBook | None = None,
) -> CsvSink | ParquetSink:
    """The sink of a run's rows in ``fmt``; with a ``book`` (a size or age cap) in parts."""
    for other in (TelemetryFormat.CSV, TelemetryFormat.CSV_GZ, TelemetryFormat.PARQUET):
        if rows_path(run_dir, other).exists():  # a run directory holds one run
            raise FileExistsError(f"{rows_path(run_dir, other)} exists")
    if (run_dir / TELEMETRY_PARTS).exists():
        raise FileExistsError(f"{run_dir / TELEMETRY_PARTS} exists")
    path = rows_path(run_dir, fmt, parts=book is not None)
    if fmt is TelemetryFormat.PARQUET:
        return ParquetSink(path, joint_names, opener, book)
    return CsvSink(path, joint_names, opener, gz=fmt is TelemetryFormat.CSV_GZ, book=book)


class CsvSink:
    """Exact CSV text, plain or gzip-compressed (module docstring)."""

    def __init__(
        self,
        path: Path,
        joint_names: Sequence[str],
        opener: Opener,
        *,
        gz: bool,
        book: PartBook | None = None,
    ) -> None:
        columns = csv_columns(joint_names)
        self.path = path  # the file, or under a cap the parts' directory
        self.chunk_rows = max(1, _CHUNK_FLOATS // len(columns))
        self.bursts = False
        self.book = book
        self._opener, self._is_gz = opener, gz
        self._fmt = row_format(len(joint_names))
        self._header = ",".join(columns) + "\n"
        self._gz: gzip.GzipFile | None = None
        self._pending: list[str] = []
        self._pending_len = self._pending_rows = 0
        self._rows_put = 0
        self.parts = 0
        # under a cap a part may pass its size by a batch (gzip) or a chunk: a quarter at most
        part = book.part_bytes if book is not None else None
        self._batch = _GZ_BATCH if part is None else max(1024, min(_GZ_BATCH, part // 4))
        if book is not None:
            path.mkdir()  # FileExistsError: a run directory holds one run
            self._open_file(self._part_path())
        else:
            self._open_file(path)

    def _part_path(self) -> Path:
        return self.path / f"part-{self.parts:05d}.csv{'.gz' if self._is_gz else ''}"

    def _open_file(self, path: Path) -> None:
        """Open ``path`` (a new file) and write the header."""
        self._file_path = path
        self._part_rows, self._part_ticks = 0, (-1, -1)
        self._part_bytes, self._opened_at = len(self._header), time.monotonic()
        if self._is_gz:
            self._file = self._opener(path, "xb")
            try:
                self._gz = gzip.GzipFile(
                    filename="", fileobj=self._file, mode="wb", compresslevel=_GZ_LEVEL, mtime=0
                )
                self._gz.write(self._header.encode("utf-8"))
                self._gz.flush()
            except BaseException:
                with contextlib.suppress(OSError, ValueError):
                    self._file.close()
                raise
        else:
            self._file = self._opener(path, "x")
            self._file.write(self._header)
        self._file.flush()
        #: (bytes, rows) of the plain file at its last flush
        self._flushed = (os.fstat(self._file.fileno()).st_size, self._rows_put)

    def take(self, ring: TickRing, n: int) -> list[list[float]]:
        return ring.take(n)

    def put(self, rows: list[list[float]]) -> int:
        fmt = self._fmt
        text = "".join([fmt % tuple(r) for r in rows])
        if self.book is not None and rows:
            first = self._part_ticks[0] if self._part_rows else int(rows[0][0])
            self._part_ticks = (first, int(rows[-1][0]))
            self._part_rows += len(rows)
        if self._gz is None:
            self._rows_put += len(rows)
            self._file.write(text)
            self._part_bytes += len(text)  # ASCII: one byte a character
            done = len(rows)
        else:
            self._pending.append(text)
            self._pending_len += len(text)
            self._pending_rows += len(rows)
            done = self._compress() if self._pending_len >= self._batch else 0
        book = self.book
        if book is not None and book.full(self._size(), self._opened_at, time.monotonic()):
            done += self._rotate(book)
        return done

    def _size(self) -> int:
        """The part's bytes so far (gzip: compressed, up to the last batch)."""
        return self._part_bytes if self._gz is None else int(self._file.tell())

    def _rotate(self, book: PartBook) -> int:
        """Close the part (the gzip trailer, fsync), make room under the caps, open the next
        part; the rows written in doing so."""
        rows = self.flush(True)
        self._close_file()
        size = self._file_path.stat().st_size
        first, last = self._part_ticks
        book.closed(Part(self._file_path, size, self._part_rows, first, last, time.time()))
        book.make_room((book.part_bytes or 0) * 5 // 4)  # the next part, and its overshoot
        self.parts += 1
        self._open_file(self._part_path())
        fsync_dir(self.path)
        return rows

    def _compress(self) -> int:
        """Compress the pending text; the rows it held (written, as far as the writer counts)."""
        if not self._pending or self._gz is None:
            return 0
        data = "".join(self._pending).encode("utf-8")
        self._gz.write(data)  # zlib compresses without holding the GIL
        rows = self._pending_rows
        self._pending.clear()
        self._pending_len = self._pending_rows = 0
        return rows

    def busy(self) -> bool:
        return False  # put() formats and writes its rows at once

    def work(self) -> None:
        return

    def flush(self, fsync: bool) -> int:
        rows = 0
        if self._gz is not None:
            rows = self._compress()
            self._gz.flush()  # a sync flush: everything so far decodes
        self._file.flush()
        if self._gz is None:
            self._flushed = (os.fstat(self._file.fileno()).st_size, self._rows_put)
        if fsync:
            os.fsync(self._file.fileno())
        return rows

    def rows_on_disk(self) -> int | None:
        """The whole rows in the file after a failure: those of its last flush, and those its
        buffer got out since (a torn last one not counted). None for gzip."""
        if self._gz is not None:
            return None
        size, rows = self._flushed
        with open(self._file_path, "rb") as f:
            f.seek(size)
            return rows + f.read().count(b"\n")

    def close(self) -> None:
        self._close_file()

    def _close_file(self) -> None:
        try:
            if self._gz is not None:
                self._gz.close()  # the gzip trailer; the file stays open
                self._gz = None
        finally:
            self._file.close()


class ParquetSink:
    """Parquet part files of fixed-point integer columns (module docstring)."""

    chunk_rows = _PARQUET_TAKE_ROWS
    bursts = True

    def __init__(
        self, path: Path, joint_names: Sequence[str], opener: Opener, book: PartBook | None = None
    ) -> None:
        import pyarrow as pa  # the optional extra: only a Parquet run imports it
        import pyarrow.parquet as pq

        self._pa, self._pq = pa, pq
        self.path = path
        self._opener = opener
        cols = parquet_columns(joint_names)
        self._names = [c.name for c in cols]
        self._types = [getattr(pa, c.dtype)() for c in cols]
        self._dtypes = [np.dtype(c.dtype) for c in cols]
        self._scale = np.array([c.scale for c in cols])
        self._schema = pa.schema(list(zip(self._names, self._types, strict=True)))
        self._encoding = {n: "DELTA_BINARY_PACKED" for n in self._names}
        self._raw: list[np.ndarray] = []  # rows taken, not yet encoded
        self._raw_rows = 0
        self._batches: list[Any] = []  # encoded, waiting for the next part
        self._job: Generator[None, None, Any] | None = None  # a batch being encoded
        self._job_rows = 0  # of that many rows
        self._rows = 0
        self._ticks = (-1, -1)  # the first and last tick of the rows waiting for a part
        self.book = book
        self.parts = 0
        path.mkdir()  # FileExistsError: a run directory holds one run
        # encode and write a throw-away part now, before the show: pyarrow's first calls
        # (lazy imports, zstd set up) cost milliseconds that would otherwise land mid-show
        self._write_table([self._batch(np.zeros((2, len(cols))))], 2)

    def take(self, ring: TickRing, n: int) -> np.ndarray:
        return ring.take_array(n)

    def put(self, rows: np.ndarray) -> int:
        if len(rows):
            first = self._ticks[0] if self._rows else int(rows[0, 0])
            self._ticks = (first, int(rows[-1, 0]))
        self._raw.append(rows)  # encoded by work(), 256 rows or more at a time
        self._raw_rows += len(rows)
        self._rows += len(rows)
        return self.flush(True) if self._rows >= _PARQUET_MAX_ROWS else 0

    def busy(self) -> bool:
        return self._job is not None or self._raw_rows >= _PARQUET_TAKE_ROWS

    def work(self) -> None:
        """One step of encoding the rows put (a slice of rows, or of columns: ~0.1 ms),
        so that the writer fits it into the loop's free time."""
        if self._job is None:
            raw = self._take_raw()
            self._job, self._job_rows = self._batch_steps(raw), len(raw)
        try:
            next(self._job)
        except StopIteration as done:
            self._batches.append(done.value)
            self._job = None
        except BaseException:
            # its rows are lost (not written, so counted lost), not left to flush as a dead job
            self._job, self._rows = None, self._rows - self._job_rows
            raise

    def _take_raw(self) -> np.ndarray:
        data = np.concatenate(self._raw) if len(self._raw) > 1 else self._raw[0]
        self._raw.clear()
        self._raw_rows = 0
        return data

    def _encode_raw(self) -> None:
        """Encode everything put, now (a flush): the batch under way first, in order."""
        while self._job is not None or self._raw:
            self.work()

    def flush(self, fsync: bool) -> int:
        """A part is written only at fsync points (a footer per flush would cost more than the
        rows: ~3 kB); between them the rows wait in memory, encoded."""
        if not fsync or not self._rows:
            return 0
        self._encode_raw()
        blob = self._write_table(self._batches, self._rows)
        final = self.path / f"part-{self.parts:05d}.parquet"
        tmp = self.path / f".part-{self.parts:05d}.tmp"  # ignored by readers of the directory
        if self.book is not None:
            self.book.make_room(blob.size)  # the oldest parts go first: the new one fits
        try:
            f = self._opener(tmp, "xb")
            try:
                f.write(memoryview(blob))
                f.flush()
                os.fsync(f.fileno())
            finally:
                f.close()
            os.replace(tmp, final)
        except BaseException:
            with contextlib.suppress(OSError):  # a full disk: leave no half part
                tmp.unlink()
            raise
        fsync_dir(self.path)
        if self.book is not None:
            first, last = self._ticks
            self.book.closed(Part(final, blob.size, self._rows, first, last, time.time()))
        self.parts += 1
        written, self._rows = self._rows, 0
        while self._batches:  # freed a batch at a time: one clear() held the GIL ~0.4 ms
            self._batches.pop()
        return written

    def _write_table(self, batches: list[Any], rows: int) -> Any:  # pyarrow's (untyped)
        pa = self._pa
        sink = pa.BufferOutputStream()
        self._pq.write_table(  # C++, without the GIL
            pa.Table.from_batches(batches, schema=self._schema),
            sink,
            row_group_size=rows,
            compression="zstd",
            compression_level=1,
            use_dictionary=False,
            column_encoding=self._encoding,
        )
        return sink.getvalue()

    def _batch(self, rows: np.ndarray) -> Any:
        """Rows (float64, CSV units) -> a record batch of fixed-point integers, at once."""
        steps = self._batch_steps(rows)
        while True:
            try:
                next(steps)
            except StopIteration as done:
                return done.value

    def _batch_steps(self, rows: np.ndarray) -> Generator[None, None, Any]:
        """:meth:`_batch` in steps of ~0.1 ms (yields between them; returns the batch):
        numpy on _PREP_ROWS rows at a time, then pyarrow on _ARROW_COLUMNS columns."""
        pa, n = self._pa, len(rows)
        q = np.empty((len(self._types), n), dtype=np.int64)  # a column per row
        nan = np.empty((len(self._types), n), dtype=bool)
        for lo in range(0, n, _PREP_ROWS):
            hi = min(n, lo + _PREP_ROWS)
            scaled = np.multiply(rows[lo:hi], self._scale).T
            bad = np.isnan(scaled)
            big = np.abs(scaled) > _INT_LIMIT  # False for NaN
            view = q[:, lo:hi]
            view[...] = np.rint(np.where(bad | big, 0.0, scaled))
            if big.any():
                view[big] = np.where(scaled[big] > 0, INT_INF, -INT_INF)
            nan[:, lo:hi] = bad
            yield
        has_nan: list[bool] = np.any(nan, axis=1).tolist()  # (np.any: typed as an array)
        arrays = []
        for k, typ in enumerate(self._types):
            col = q[k] if self._dtypes[k] == np.int64 else q[k].astype(self._dtypes[k])
            arrays.append(pa.array(col, type=typ, mask=nan[k] if has_nan[k] else None))
            if k % _ARROW_COLUMNS == _ARROW_COLUMNS - 1:
                yield
        return pa.RecordBatch.from_arrays(arrays, schema=self._schema)

    def rows_on_disk(self) -> int | None:
        return None  # parts are written whole: the rows counted are the rows there

    def close(self) -> None:
        self._raw.clear()
        self._job = None
        self._batches.clear()  # rows not flushed by now are lost (the writer counts them)


def fsync_dir(path: Path) -> None:
    """Persist directory entries (new files, renames); best effort, POSIX only."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
