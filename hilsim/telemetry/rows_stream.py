"""The rows of a run read a chunk at a time (a bounded read), and the CSV header and row parsers
:mod:`hilsim.telemetry.reader` shares.

:func:`stream_rows` opens a run's rows in any format (``telemetry.csv``, ``.csv.gz``,
``telemetry.parts/``, ``telemetry.parquet/``) and yields float64 arrays of a few thousand rows
in the CSV's columns and units, so a reader that keeps a bounded summary of them
(:class:`hilsim.telemetry.envelope.Envelope`) never holds the whole table. What was tolerated
(a cut-off last line or gzip stream, a damaged part) is said in its warnings, as the whole read
does.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hilsim.telemetry.format import (
    HEAD_COLUMNS,
    JOINT_FIELDS,
    TAILS,
    TELEMETRY_PARQUET,
    ParquetColumn,
    TelemetryError,
    csv_columns,
    parquet_columns,
)
from hilsim.telemetry.sinks import INT_INF

_CHUNK_BYTES = 1 << 22  # text parsed at a time: ~10k rows of the demo


class RunFormatError(TelemetryError, ValueError):
    """The rows are not telemetry (a CSV without a telemetry header, Parquet parts without its
    columns), or cannot be read here (Parquet without pyarrow)."""


def parse_header(line: str) -> tuple[list[str], tuple[str, ...], int]:
    """The header's names, its joints and its layout's version."""
    names = line.rstrip("\r\n").split(",")
    for version, tail_columns in sorted(TAILS.items(), reverse=True):
        head, tail = len(HEAD_COLUMNS), len(tail_columns)
        middle = names[head : len(names) - tail]
        ok = (
            len(names) >= head + tail + len(JOINT_FIELDS)
            and tuple(names[:head]) == HEAD_COLUMNS
            and tuple(names[len(names) - tail :]) == tail_columns
            and len(middle) % len(JOINT_FIELDS) == 0
        )
        if ok:
            n = len(middle) // len(JOINT_FIELDS)
            prefix = JOINT_FIELDS[0] + "_"
            joints = tuple(c[len(prefix) :] for c in middle[:n])
            ok = (
                all(c.startswith(prefix) for c in middle[:n])
                and middle == csv_columns(joints, version)[head : len(names) - tail]
            )
            if ok:
                return names, joints, version
    raise RunFormatError(f"not a telemetry header: {line[:120]!r}")


def parse_rows(
    lines: list[str], ncols: int, warnings: list[str], name: str, first_line: int = 2
) -> np.ndarray:
    """Rows of floats from CSV lines (``first_line``: the file line of ``lines[0]``, for the
    warnings); what does not parse is skipped and said."""
    if not lines:
        return np.empty((0, ncols))
    try:
        data = np.loadtxt(lines, delimiter=",", dtype=np.float64, ndmin=2, comments=None)
        if data.shape[1] == ncols:
            return data
    except ValueError:
        pass
    # slow path: skip what does not parse, accept empty fields as NaN
    rows: list[list[float]] = []
    bad: list[int] = []
    for i, line in enumerate(lines):
        parts = line.rstrip("\r").split(",")
        try:
            if len(parts) != ncols:
                raise ValueError
            rows.append([float(p) if p else math.nan for p in parts])
        except ValueError:
            bad.append(i + first_line)  # 1-based file line
    if bad:
        shown = ", ".join(map(str, bad[:10])) + (" ..." if len(bad) > 10 else "")
        warnings.append(f"{name}: skipped {len(bad)} unparsable line(s): {shown}")
    return np.array(rows, dtype=np.float64).reshape(-1, ncols)


@dataclass(eq=False)
class RowStream:
    """A run's rows, a chunk at a time: its CSV column names, joints, layout version, and
    :meth:`chunks`. ``truncated`` is True once a cut-off last line was met."""

    names: list[str]
    joints: tuple[str, ...]
    version: int
    _chunks: Iterator[np.ndarray]
    truncated: bool = False
    warnings: list[str] = field(default_factory=list)

    def chunks(self) -> Iterator[np.ndarray]:
        return self._chunks


def _text_pieces(path: Path, warnings: list[str]) -> Iterator[bytes]:
    """The file's bytes a piece at a time, gunzipped for ``.gz`` (a cut-off or damaged stream:
    what decodes, then a warning)."""
    with open(path, "rb") as f:
        if path.suffix != ".gz":
            while piece := f.read(_CHUNK_BYTES):
                yield piece
            return
        d = zlib.decompressobj(wbits=31)
        done = 0
        while raw := f.read(_CHUNK_BYTES // 4):
            try:
                out = [d.decompress(raw)]
                while d.eof and d.unused_data:  # another gzip member follows
                    rest, d = d.unused_data, zlib.decompressobj(wbits=31)
                    out.append(d.decompress(rest))
            except zlib.error as exc:
                warnings.append(f"{path.name}: damaged after {done} bytes of text ({exc})")
                return
            text = b"".join(out)
            done += len(text)
            yield text
        if not d.eof:
            warnings.append(f"{path.name}: the gzip stream is cut off (the run ended abruptly)")


def _csv_lines(path: Path, warnings: list[str], stream: list[bool]) -> Iterator[list[str]]:
    """Complete lines, a list per piece; a cut-off last line (or NUL tail) is dropped and said
    (``stream[0]`` set True)."""
    carry = b""
    for piece in _text_pieces(path, warnings):
        data = carry + piece
        cut = data.rfind(b"\n") + 1
        carry = data[cut:]
        lines = data[:cut].decode("utf-8", errors="replace").split("\n")
        yield [ln for ln in lines if ln.strip()]
    partial = carry.rstrip(b"\x00")
    if partial:
        warnings.append(
            f"{path.name}: last line is incomplete ({len(partial)} chars, "
            "the run probably ended abruptly); ignored"
        )
        stream[0] = True


def _csv_stream(files: list[Path], warnings: list[str]) -> RowStream:
    """CSV files (one, or parts with a header each) as one stream of rows."""
    first = iter(_csv_lines(files[0], warnings, cut := [False]))
    lines: list[str] = []
    for lines in first:
        if lines:
            break
    if not lines:
        raise RunFormatError(f"{files[0]} has no header")
    names, joints, version = parse_header(lines[0])

    def chunks() -> Iterator[np.ndarray]:
        yield parse_rows(lines[1:], len(names), warnings, files[0].name)
        for i, f in enumerate(files):
            pieces = first if i == 0 else iter(_csv_lines(f, warnings, cut))
            at = 1 + len(lines) if i == 0 else 2
            for n, more in enumerate(pieces):
                if i > 0 and n == 0 and more:
                    if parse_header(more[0])[0] != names:
                        raise RunFormatError(f"{f}: parts with different columns")
                    more = more[1:]
                yield parse_rows(more, len(names), warnings, f.name, at)
                at += len(more)
        stream.truncated = cut[0]

    stream = RowStream(names, joints, version, chunks(), warnings=warnings)
    return stream


def parquet_table_columns(table: Any, cols: list[ParquetColumn]) -> dict[str, np.ndarray]:
    """A Parquet table's columns (pyarrow's) in CSV names and units: nulls NaN,
    +-(2**63 - 1) +-inf."""
    out = {}
    for c in cols:
        q = np.asarray(table.column(c.name).to_numpy(zero_copy_only=False), dtype=np.float64)
        x = q / c.scale
        inf = np.abs(q) >= float(INT_INF)
        x[inf] = np.copysign(math.inf, q[inf])
        out[c.csv] = x
    return out


def parquet_joints(first: list[str]) -> tuple[tuple[str, ...], int | None]:
    """The joints and layout version of Parquet parts whose columns are ``first``."""
    prefix, suffix = JOINT_FIELDS[0] + "_", "_urad"
    joints = tuple(
        c[len(prefix) : -len(suffix)] for c in first if c.startswith(prefix) and c.endswith(suffix)
    )
    layouts = {v: parquet_columns(joints, v) for v in TAILS} if joints else {}
    version = next((v for v, cols in layouts.items() if [c.name for c in cols] == first), None)
    return joints, version


def _parquet_stream(pq_dir: Path, warnings: list[str]) -> RowStream:
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise RunFormatError(
            f"{pq_dir} is Parquet: reading it needs pyarrow (pip install 'hilsim[parquet]')"
        ) from None
    parts = sorted(pq_dir.glob("part-*.parquet"))
    schema = None
    for part in parts:
        try:
            schema = pq.read_schema(part)
            break
        except Exception as exc:  # a damaged part: the others still read
            warnings.append(f"{TELEMETRY_PARQUET}/{part.name}: unreadable, skipped ({exc})")
    if schema is None:
        raise RunFormatError(f"{pq_dir} holds no readable part-*.parquet yet")
    first = list(schema.names)
    joints, version = parquet_joints(first)
    if version is None:
        raise RunFormatError(f"{pq_dir}: not telemetry columns: {first[:6]!r} ...")
    cols = parquet_columns(joints, version)
    names = [c.csv for c in cols]

    def chunks() -> Iterator[np.ndarray]:
        for part in parts:
            try:
                table = pq.read_table(part)
            except Exception as exc:
                if not any(part.name in w for w in warnings):
                    warnings.append(f"{TELEMETRY_PARQUET}/{part.name}: unreadable, skipped ({exc})")
                continue
            if table.column_names != first:
                raise RunFormatError(f"{pq_dir}: parts with different columns")
            got = parquet_table_columns(table, cols)
            yield np.column_stack([got[n] for n in names]).reshape(-1, len(names))

    return RowStream(names, joints, version, chunks(), warnings=warnings)


def stream_rows(path: Path, warnings: list[str]) -> RowStream:
    """The rows at ``path`` (a CSV file, a ``telemetry.parts/`` or ``telemetry.parquet/``
    directory) as a :class:`RowStream`; what is tolerated goes into ``warnings``."""
    if path.is_dir() and path.name == TELEMETRY_PARQUET:
        return _parquet_stream(path, warnings)
    if path.is_dir():
        files = sorted(p for p in path.glob("part-*.csv*") if p.suffix in (".csv", ".gz"))
        if not files:
            raise RunFormatError(f"{path} holds no part-*.csv yet")
        return _csv_stream(files, warnings)
    return _csv_stream([path], warnings)
