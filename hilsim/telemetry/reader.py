"""Reading a run back: :func:`read_run` loads a run directory into a :class:`Run`.

The directory's format is in :mod:`hilsim.telemetry.format`: its rows in ``telemetry.csv``,
``telemetry.csv.gz`` or ``telemetry.parquet/`` (whichever is there), read into the same columns
(CSV names and units) whatever the format. A run being written, or cut short by a crash, still
loads: what was tolerated is listed in ``Run.warnings`` (a gzip stream cut off: everything up to
the cut; a Parquet part that does not read: skipped). A gap in the ticks is told apart from the
rows themselves (their ``skipped_ticks``): ticks the loop caught up on without a row, or rows lost.
"""

from __future__ import annotations

import contextlib
import json
import os
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from hilsim.telemetry.envelope import Envelope
from hilsim.telemetry.format import (
    CONFIG_NAME,
    EVENTS_JSONL,
    JOINT_FIELDS,
    ROWS_SCHEMA_VERSION,
    SUMMARY_JSON,
    TELEMETRY_CSV,
    TELEMETRY_CSV_GZ,
    TELEMETRY_PARQUET,
    TELEMETRY_PARTS,
    TelemetryError,
    parquet_columns,
)
from hilsim.telemetry.rows_stream import (
    RunFormatError,
    parquet_joints,
    parquet_table_columns,
    parse_header,
    parse_rows,
    stream_rows,
)


class NotARunError(TelemetryError, FileNotFoundError):
    """The directory holds no ``telemetry.csv`` (nor ``.csv.gz``, nor ``telemetry.parquet/``)."""


@dataclass(eq=False)
class Run:
    """One run directory, loaded. Columns are float64 arrays shaped ``(ticks,)`` by CSV name.

    ``warnings`` lists what was tolerated: a truncated last line (crash mid-write), unparsable
    lines, tick gaps (caught up by the loop, or rows lost), a missing or corrupt summary.
    ``truncated`` is True when the CSV's last line was cut off. ``rows_file`` names what the rows
    were read from (``telemetry.parquet`` ...), ``rows_version`` their columns' layout
    (:data:`~hilsim.telemetry.format.ROWS_SCHEMA_VERSION`; 1 has no ``skipped_ticks``).
    """

    path: Path
    joint_names: tuple[str, ...]
    columns: dict[str, np.ndarray]
    events: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    config_text: str | None = None
    warnings: list[str] = field(default_factory=list)
    truncated: bool = False
    rows_file: str = TELEMETRY_CSV
    rows_version: int = ROWS_SCHEMA_VERSION
    #: a bounded read of a long run (``read_run(..., max_rows=)``): the min/max envelope and
    #: its exact counts (:mod:`hilsim.telemetry.envelope`); the columns then hold two rows a
    #: bucket when :attr:`decimated`, else the rows themselves
    envelope: Envelope | None = None
    #: per row of ``columns``: the envelope's counts (rows, overruns, bad reads, acted, stage sums)
    counts: dict[str, np.ndarray] | None = None

    @property
    def decimated(self) -> bool:
        """The columns are a min/max envelope (two rows a bucket), not the rows themselves."""
        return self.envelope is not None and self.envelope.decimated

    @property
    def n_ticks(self) -> int:
        return int(self.columns["tick"].size)

    @cached_property
    def tick(self) -> np.ndarray:
        return self.columns["tick"].astype(np.int64)

    @property
    def t_sched(self) -> np.ndarray:
        return self.columns["t_sched"]

    @property
    def t_actual(self) -> np.ndarray:
        return self.columns["t_actual"]

    @property
    def lateness_us(self) -> np.ndarray:
        return self.columns["lateness_us"]

    @property
    def overrun(self) -> np.ndarray:
        overrun: np.ndarray = self.columns["overrun"] != 0
        return overrun

    @property
    def comm_errors(self) -> np.ndarray:
        return self.columns["comm_errors"].astype(np.int64)

    @property
    def caught_up(self) -> int | None:
        """Ticks the loop caught up on without a row before the last row (its ``skipped_ticks``);
        None when the rows do not say (layout 1, or no readable count)."""
        skipped = self.columns.get("skipped_ticks")
        if skipped is None:
            return None
        known = skipped[np.isfinite(skipped)]
        return int(known[-1]) if known.size and known[-1] >= 0 else None

    def joint(self, quantity: str) -> np.ndarray:
        """``(ticks, n_joints)`` array of one :data:`JOINT_FIELDS` quantity (``status``: int8)."""
        if quantity not in JOINT_FIELDS:
            raise KeyError(f"{quantity!r} is not one of {JOINT_FIELDS}")
        out = np.column_stack([self.columns[f"{quantity}_{j}"] for j in self.joint_names])
        out = out.reshape(self.n_ticks, len(self.joint_names))
        return out.astype(np.int8) if quantity == "status" else out

    def stage_us(self, stage: str) -> np.ndarray:
        """``(ticks,)`` wall time of one :data:`STAGES` entry, µs."""
        return self.columns[f"t_{stage}_us"]


def _gunzip(path: Path, warnings: list[str]) -> bytes:
    """A gzip file's text as far as it decodes: a stream cut off by a crash gives everything up
    to the cut (the writer sync-flushes at every flush), damage ends it where it starts."""
    raw = path.read_bytes()
    out: list[bytes] = []
    d = zlib.decompressobj(wbits=31)
    piece = 1 << 12
    for at in range(0, len(raw), piece):
        before = d.copy()
        try:
            out.append(d.decompress(raw[at : at + piece]))
            while d.eof and d.unused_data:  # another gzip member follows
                rest, d = d.unused_data, zlib.decompressobj(wbits=31)
                out.append(d.decompress(rest))
        except zlib.error as exc:  # keep what the piece held before the damage, byte by byte
            d = before
            with contextlib.suppress(zlib.error):
                for b in range(at, min(at + piece, len(raw))):
                    out.append(d.decompress(raw[b : b + 1]))
            text = sum(map(len, out))
            warnings.append(f"{path.name}: damaged after {text} bytes of text ({exc})")
            return b"".join(out)
    if not d.eof:
        warnings.append(f"{path.name}: the gzip stream is cut off (the run ended abruptly)")
    return b"".join(out)


def _read_lines(path: Path, warnings: list[str]) -> tuple[list[str], bool]:
    """Complete lines of a text file; a cut-off last line (or NUL tail) is dropped and reported.
    A ``.gz`` file is decompressed first."""
    data = _gunzip(path, warnings) if path.suffix == ".gz" else path.read_bytes()
    data = data.rstrip(b"\x00")
    text = data.decode("utf-8", errors="replace")
    lines = text.split("\n")
    partial = lines.pop()  # "" when the file ends with a newline
    if partial:
        warnings.append(
            f"{path.name}: last line is incomplete ({len(partial)} chars, "
            "the run probably ended abruptly); ignored"
        )
    return [ln for ln in lines if ln.strip()], bool(partial)


#: the rows' columns, the joint names, whether the last line was cut, the rows' version
_Rows = tuple[dict[str, np.ndarray], tuple[str, ...], bool, int]


def _read_csv(csv_path: Path, warnings: list[str]) -> _Rows:
    lines, truncated = _read_lines(csv_path, warnings)
    if not lines:
        raise RunFormatError(f"{csv_path} has no header")
    names, joints, version = parse_header(lines[0])
    data = parse_rows(lines[1:], len(names), warnings, csv_path.name)
    return {name: data[:, k].copy() for k, name in enumerate(names)}, joints, truncated, version


def _read_csv_parts(parts_dir: Path, warnings: list[str]) -> _Rows:
    """CSV parts (``part-NNNNN.csv`` or ``.csv.gz``, a header each), in order, as one table.
    The oldest parts may have been removed under a cap (the rows start later)."""
    files = sorted(p for p in parts_dir.glob("part-*.csv*") if p.suffix in (".csv", ".gz"))
    if not files:
        raise RunFormatError(f"{parts_dir} holds no part-*.csv yet")
    tables = [_read_csv(f, warnings) for f in files]
    joints, version = tables[0][1], tables[0][3]
    if any(t[1] != joints or t[3] != version for t in tables):
        raise RunFormatError(f"{parts_dir}: parts with different columns")
    columns = {name: np.concatenate([t[0][name] for t in tables]) for name in tables[0][0]}
    return columns, joints, tables[-1][2], version


def _read_parquet(pq_dir: Path, warnings: list[str]) -> _Rows:
    """Parquet parts -> CSV columns in CSV units (format.py: the Parquet columns)."""
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise RunFormatError(
            f"{pq_dir} is Parquet: reading it needs pyarrow (pip install 'hilsim[parquet]')"
        ) from None
    tables = []
    for part in sorted(pq_dir.glob("part-*.parquet")):
        try:
            tables.append(pq.read_table(part))
        except Exception as exc:  # a damaged part: the others still read
            warnings.append(f"{TELEMETRY_PARQUET}/{part.name}: unreadable, skipped ({exc})")
    if not tables:
        raise RunFormatError(
            f"{pq_dir} holds no readable part-*.parquet yet (a part is written at each fsync of "
            "the writer, every 2 s, and at the end)"
        )
    first = tables[0].column_names
    joints, version = parquet_joints(first)
    if version is None:
        raise RunFormatError(f"{pq_dir}: not telemetry columns: {first[:6]!r} ...")
    cols = parquet_columns(joints, version)
    if any(t.column_names != first for t in tables):
        raise RunFormatError(f"{pq_dir}: parts with different columns")
    got = [parquet_table_columns(t, cols) for t in tables]
    columns = {c.csv: np.concatenate([g[c.csv] for g in got]) for c in cols}
    return columns, joints, False, version


def _read_events(ev_path: Path, warnings: list[str]) -> list[dict[str, Any]]:
    """The events, one JSON object a line; what does not parse is skipped and said."""
    events: list[dict[str, Any]] = []
    if ev_path.is_file():
        ev_lines, _ = _read_lines(ev_path, warnings)
        bad = 0
        for ln in ev_lines:
            try:
                obj = json.loads(ln)
            except ValueError:
                bad += 1
                continue
            if isinstance(obj, dict):
                events.append(obj)
            else:
                bad += 1
        if bad:
            warnings.append(f"{EVENTS_JSONL}: skipped {bad} unparsable line(s)")
    else:
        warnings.append(f"no {EVENTS_JSONL}")
    return events


def _read_bounded(
    rows_path: Path, warnings: list[str], max_rows: int
) -> tuple[_Rows, Envelope, tuple[int, int, int]]:
    """The rows streamed into an :class:`Envelope` (bounded memory), and the tick gaps counted
    on the way (:func:`tick_gaps`, across chunk edges too)."""
    stream = stream_rows(rows_path, warnings)
    env = Envelope(stream.names, stream.joints, max_rows=max_rows)
    gaps = [0, 0, 0]
    last: np.ndarray | None = None
    want = [k for k, n in enumerate(stream.names) if n in ("tick", "skipped_ticks", "overrun")]
    for chunk in stream.chunks():
        if not len(chunk):
            continue
        edge = chunk[:, want] if last is None else np.vstack([last, chunk[:, want]])
        cols = {stream.names[k]: edge[:, i] for i, k in enumerate(want)}
        for i, n in enumerate(tick_gaps(cols)):
            gaps[i] += n
        last = chunk[-1:, want]
        env.add(chunk)
    env.finish()
    columns, counts = env.columns()
    rows: _Rows = (columns, stream.joints, stream.truncated, stream.version)
    env.counted = counts
    return rows, env, (gaps[0], gaps[1], gaps[2])


def read_run(run_dir: str | os.PathLike[str], *, max_rows: int | None = None) -> Run:
    """Load a run directory written by :class:`TelemetryWriter` (possibly while it is written,
    or after a crash), whatever its rows' format. Raises :class:`NotARunError` if it holds no
    rows (``telemetry.csv``, ``.csv.gz``, ``telemetry.parquet/``) and :class:`RunFormatError` if
    they are not telemetry (or Parquet without pyarrow); everything else that is wrong is
    tolerated and listed in ``Run.warnings``.

    ``max_rows``: a bounded read: the rows are streamed, and past ``max_rows`` kept as a
    min/max envelope per bucket of ticks with exact counts (``Run.envelope``,
    :mod:`hilsim.telemetry.envelope`), so a run of any length reads in the same memory."""
    path = Path(run_dir)
    warnings: list[str] = []
    read: Callable[[Path, list[str]], _Rows]
    if (path / TELEMETRY_CSV).is_file():
        rows_file, read = TELEMETRY_CSV, _read_csv
    elif (path / TELEMETRY_CSV_GZ).is_file():
        rows_file, read = TELEMETRY_CSV_GZ, _read_csv
    elif (path / TELEMETRY_PARQUET).is_dir():
        rows_file, read = TELEMETRY_PARQUET, _read_parquet
    elif (path / TELEMETRY_PARTS).is_dir():
        rows_file, read = TELEMETRY_PARTS, _read_csv_parts
    else:
        raise NotARunError(
            f"{path} holds no per-tick rows (no {TELEMETRY_CSV}, {TELEMETRY_CSV_GZ}, "
            f"{TELEMETRY_PARTS} or {TELEMETRY_PARQUET}: not a run directory, or one with "
            "telemetry.format = 'none')"
        )
    envelope, gaps = None, None
    if max_rows is None:
        columns, joints, truncated, version = read(path / rows_file, warnings)
    else:
        (columns, joints, truncated, version), envelope, gaps = _read_bounded(
            path / rows_file, warnings, max_rows
        )
    decimated = envelope is not None and envelope.decimated  # (two rows a bucket)
    if not decimated and columns["tick"].size > 1 and np.any(np.diff(columns["tick"]) < 1):
        warnings.append(f"{rows_file}: tick numbers are not increasing")

    events = _read_events(path / EVENTS_JSONL, warnings)

    summary: dict[str, Any] | None = None
    sum_path = path / SUMMARY_JSON
    if sum_path.is_file():
        try:
            loaded = json.loads(sum_path.read_text(encoding="utf-8"))
            summary = loaded if isinstance(loaded, dict) else None
        except ValueError as exc:
            warnings.append(f"{SUMMARY_JSON}: unreadable ({exc})")
    else:
        warnings.append(f"no {SUMMARY_JSON} (the run did not close cleanly, or is still running)")
    warnings.extend(gap_warnings(rows_file, columns, summary, gaps))
    tel = summary.get("telemetry") if summary else None
    rotated = [e for e in events if e.get("kind") == "telemetry_rotated"]
    if rotated:
        gone = sum(int(e.get("rows") or 0) for e in rotated)
        warnings.append(
            f"{rows_file}: the oldest {len(rotated)} part(s) ({gone} rows, to tick "
            f"{rotated[-1].get('last_tick')}) removed under the run's cap (telemetry_rotated)"
        )
    if isinstance(tel, dict):
        if tel.get("rows_dropped"):
            warnings.append(
                f"{tel['rows_dropped']} row(s) dropped while recording "
                "(the writer fell behind: a stalled disk or no CPU for it)"
            )
        if tel.get("rows_lost"):
            warnings.append(
                f"{tel['rows_lost']} recorded row(s) never written ({tel.get('error')})"
            )

    cfg = path / CONFIG_NAME
    config_text = cfg.read_text(encoding="utf-8") if cfg.is_file() else None
    return Run(
        path=path,
        joint_names=joints,
        columns=columns,
        events=events,
        summary=summary,
        config_text=config_text,
        warnings=warnings,
        truncated=truncated,
        rows_file=rows_file,
        rows_version=version,
        envelope=envelope,
        counts=None if envelope is None else envelope.counted or None,
    )


def tick_gaps(columns: dict[str, np.ndarray]) -> tuple[int, int, int]:
    """The ticks between rows that have no row: ``(caught_up, lost, unknown)``.

    Caught up: the loop simulated them without bus traffic after an overrun (no row by design),
    as the rows' cumulative ``skipped_ticks`` says across each gap. Lost: the loop ran them but
    their rows are not here (dropped while recording, or unreadable). Unknown: rows without a
    ``skipped_ticks`` (layout 1, or a value not readable) after an overrun, which the loop may
    have caught up on; after a tick that was on time there is no catch-up, so those are lost.
    """
    tick = columns["tick"]
    if tick.size < 2:
        return 0, 0, 0
    at = np.flatnonzero(np.diff(tick) > 1)
    missing = (tick[at + 1] - tick[at] - 1).astype(np.int64)
    skipped = columns.get("skipped_ticks")
    said = np.full(at.size, np.nan) if skipped is None else skipped[at + 1] - skipped[at]
    known = np.isfinite(said) & (said >= 0)
    caught = np.minimum(np.where(known, said, 0), missing).astype(np.int64)
    after_overrun = columns["overrun"][at] != 0
    unknown = np.where(~known & after_overrun, missing, 0)
    lost = missing - caught - unknown
    return int(caught.sum()), int(lost.sum()), int(unknown.sum())


def gap_warnings(
    rows_file: str,
    columns: dict[str, np.ndarray],
    summary: dict[str, Any] | None,
    gaps: tuple[int, int, int] | None = None,
) -> list[str]:
    """What :func:`tick_gaps` found (or ``gaps``, counted already), one line each, naming the
    rows' file. Rows without a ``skipped_ticks`` column fall back on the summary's
    ``loop.skipped_ticks`` if there is one."""
    caught, lost, unknown = tick_gaps(columns) if gaps is None else gaps
    loop = (summary or {}).get("loop")
    skipped = loop.get("skipped_ticks") if isinstance(loop, dict) else None
    if unknown and "skipped_ticks" not in columns and type(skipped) is int and skipped >= 0:
        # the summary counts every tick caught up on (some perhaps after the last row)
        caught = min(skipped, unknown)
        lost, unknown = lost + unknown - caught, 0
    out = []
    if caught:
        out.append(
            f"{rows_file}: {caught} tick(s) caught up by the loop without a row "
            "(simulated without bus traffic after overruns)"
        )
    if unknown:
        out.append(
            f"{rows_file}: {unknown} tick(s) without a row after overruns: caught up by the loop "
            "or rows lost (these rows do not count the ticks caught up, and no summary says it)"
        )
    if lost > 0:
        out.append(
            f"{rows_file}: {lost} tick(s) missing: the loop ran them but their rows were lost "
            "(dropped while recording, or unreadable)"
        )
    return out
