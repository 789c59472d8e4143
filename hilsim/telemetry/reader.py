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
import math
import os
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from hilsim.telemetry.format import (
    CONFIG_NAME,
    EVENTS_JSONL,
    HEAD_COLUMNS,
    JOINT_FIELDS,
    ROWS_SCHEMA_VERSION,
    SUMMARY_JSON,
    TAILS,
    TELEMETRY_CSV,
    TELEMETRY_CSV_GZ,
    TELEMETRY_PARQUET,
    TelemetryError,
    csv_columns,
    parquet_columns,
)
from hilsim.telemetry.sinks import INT_INF


class NotARunError(TelemetryError, FileNotFoundError):
    """The directory holds no ``telemetry.csv`` (nor ``.csv.gz``, nor ``telemetry.parquet/``)."""


class RunFormatError(TelemetryError, ValueError):
    """The rows are not telemetry (a CSV without a telemetry header, Parquet parts without its
    columns), or cannot be read here (Parquet without pyarrow)."""


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


def _parse_header(line: str) -> tuple[list[str], tuple[str, ...], int]:
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


def _parse_rows(lines: list[str], ncols: int, warnings: list[str], name: str) -> np.ndarray:
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
            bad.append(i + 2)  # 1-based file line, after the header
    if bad:
        shown = ", ".join(map(str, bad[:10])) + (" ..." if len(bad) > 10 else "")
        warnings.append(f"{name}: skipped {len(bad)} unparsable line(s): {shown}")
    return np.array(rows, dtype=np.float64).reshape(-1, ncols)


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
    names, joints, version = _parse_header(lines[0])
    data = _parse_rows(lines[1:], len(names), warnings, csv_path.name)
    return {name: data[:, k].copy() for k, name in enumerate(names)}, joints, truncated, version


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
    prefix, suffix = JOINT_FIELDS[0] + "_", "_urad"
    joints = tuple(
        c[len(prefix) : -len(suffix)] for c in first if c.startswith(prefix) and c.endswith(suffix)
    )
    layouts = {v: parquet_columns(joints, v) for v in TAILS} if joints else {}
    version = next((v for v, cols in layouts.items() if [c.name for c in cols] == first), None)
    if version is None:
        raise RunFormatError(f"{pq_dir}: not telemetry columns: {first[:6]!r} ...")
    cols = layouts[version]
    columns: dict[str, np.ndarray] = {}
    for c in cols:
        parts = []
        for t in tables:
            if t.column_names != first:
                raise RunFormatError(f"{pq_dir}: parts with different columns")
            # nulls come out as NaN (the column as floats); +-(2**63 - 1) is +-inf
            q = np.asarray(t.column(c.name).to_numpy(zero_copy_only=False), dtype=np.float64)
            x = q / c.scale
            inf = np.abs(q) >= float(INT_INF)
            x[inf] = np.copysign(math.inf, q[inf])
            parts.append(x)
        columns[c.csv] = np.concatenate(parts)
    return columns, joints, False, version


def read_run(run_dir: str | os.PathLike[str]) -> Run:
    """Load a run directory written by :class:`TelemetryWriter` (possibly while it is written,
    or after a crash), whatever its rows' format. Raises :class:`NotARunError` if it holds no
    rows (``telemetry.csv``, ``.csv.gz``, ``telemetry.parquet/``) and :class:`RunFormatError` if
    they are not telemetry (or Parquet without pyarrow); everything else that is wrong is
    tolerated and listed in ``Run.warnings``."""
    path = Path(run_dir)
    warnings: list[str] = []
    read: Callable[[Path, list[str]], _Rows]
    if (path / TELEMETRY_CSV).is_file():
        rows_file, read = TELEMETRY_CSV, _read_csv
    elif (path / TELEMETRY_CSV_GZ).is_file():
        rows_file, read = TELEMETRY_CSV_GZ, _read_csv
    elif (path / TELEMETRY_PARQUET).is_dir():
        rows_file, read = TELEMETRY_PARQUET, _read_parquet
    else:
        raise NotARunError(
            f"{path} is not a run directory (no {TELEMETRY_CSV}, {TELEMETRY_CSV_GZ} "
            f"or {TELEMETRY_PARQUET})"
        )
    columns, joints, truncated, version = read(path / rows_file, warnings)
    if columns["tick"].size > 1 and np.any(np.diff(columns["tick"]) < 1):
        warnings.append(f"{rows_file}: tick numbers are not increasing")

    events: list[dict[str, Any]] = []
    ev_path = path / EVENTS_JSONL
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
    warnings.extend(gap_warnings(rows_file, columns, summary))
    tel = summary.get("telemetry") if summary else None
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
    rows_file: str, columns: dict[str, np.ndarray], summary: dict[str, Any] | None
) -> list[str]:
    """What :func:`tick_gaps` found, one line each, naming the rows' file. Rows without a
    ``skipped_ticks`` column fall back on the summary's ``loop.skipped_ticks`` if there is one."""
    caught, lost, unknown = tick_gaps(columns)
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
