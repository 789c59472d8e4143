"""The run directory's format, shared by the writer and the reader: file names, CSV columns.

A run directory holds ``telemetry.csv`` (or ``telemetry.csv.gz``, or Parquet parts under
``telemetry.parquet/``), ``events.jsonl``, ``summary.json``, ``rig.toml`` and, on failure,
``telemetry_error.txt``. :class:`hilsim.telemetry.TelemetryWriter` writes it;
:func:`hilsim.telemetry.reader.read_run` reads it.

A row has a head (``tick``, times, lateness), then one block per quantity in
:data:`JOINT_FIELDS` (a column per joint), then :data:`TAIL_COLUMNS` (stage times, overrun,
comm errors, host stall, skipped ticks). :func:`csv_columns` and :func:`parquet_columns` name
the columns; :data:`ROWS_SCHEMA_VERSION` is the layout's version.

Floats are written with ``%.17g`` (exact round-trip), µs with ``%.3f``, a missing value as
``nan``. Parquet holds the same columns as integers in ns, µrad and µrad/s.

Every file and column, with units: ``docs/telemetry.md``. The summary's keys:
``docs/summary.md``. :class:`TelemetryError` is the base of the errors raised writing or
reading a run directory.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

TELEMETRY_CSV = "telemetry.csv"
TELEMETRY_CSV_GZ = "telemetry.csv.gz"
TELEMETRY_PARQUET = "telemetry.parquet"  # a directory of part files
TELEMETRY_PARTS = "telemetry.parts"  # CSV (or csv.gz) rows in parts, under a size or age cap
SHOW_MANIFEST = "show_files.json"  # the show file and the files it names: copied or hashed
EVENTS_JSONL = "events.jsonl"
SUMMARY_JSON = "summary.json"
CONFIG_NAME = "rig.toml"
TRACEBACK_TXT = "telemetry_error.txt"
RESERVE_NAME = "summary.reserve"
#: the version of summary.json's layout (docs/summary.md); raised when a key changes meaning
SUMMARY_SCHEMA_VERSION = 1

#: columns before the per-joint blocks
HEAD_COLUMNS: tuple[str, ...] = ("tick", "t_sched", "t_actual", "lateness_us")
#: per-joint quantities; the CSV has one block of columns ``<field>_<joint>`` per field, in order
JOINT_FIELDS: tuple[str, ...] = ("target", "sim_x", "sim_v", "cmd", "present", "status")
#: loop stages timed every tick; column ``t_<stage>_us``
STAGES: tuple[str, ...] = ("sim", "safety", "bus", "telemetry")
#: columns after the per-joint blocks
TAIL_COLUMNS: tuple[str, ...] = (
    *(f"t_{s}_us" for s in STAGES),
    "overrun",
    "comm_errors",
    "host_stall_us",
    "skipped_ticks",
)

#: the TickRecord attributes behind TAIL_COLUMNS, in column order
TAIL_FIELDS: tuple[str, ...] = TAIL_COLUMNS

#: the rows' column layout written now; raised when a column is added, removed or changes meaning
ROWS_SCHEMA_VERSION = 2
#: each version's tail columns (the head and per-joint blocks have not changed): version 1 had
#: no ``skipped_ticks``, so a gap in its rows after an overrun cannot be told from lost rows
TAILS: dict[int, tuple[str, ...]] = {1: TAIL_COLUMNS[:-1], 2: TAIL_COLUMNS}


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


def to_json(obj: Any, **kw: Any) -> str:
    """The JSON text of an event or a summary: numpy numbers and arrays as numbers and lists,
    paths as text, sets as lists, anything else as its ``repr``."""
    return json.dumps(obj, default=_json_default, ensure_ascii=False, **kw)


def _nan_array() -> npt.NDArray[np.float64]:
    return np.full(0, math.nan)


@dataclass(slots=True, eq=False)
class TickRecord:
    """One tick's row, filled in place by the loop and handed to ``TelemetryWriter.record``.

    The loop makes one and keeps it: the array fields are *its own buffers* (referenced, not
    copied; ``record`` copies them into the ring), the scalars are overwritten each tick. Each
    attribute is one CSV column or one block of per-joint columns (``docs/telemetry.md``;
    ``target`` … ``status`` are the :data:`JOINT_FIELDS`). Stage times not known yet are NaN;
    :meth:`TelemetryWriter.amend` writes the late ones (``t_sim_us``, ``t_telemetry_us``,
    ``overrun``) once the tick is over.
    """

    target: npt.NDArray[np.float64] = field(default_factory=_nan_array)
    sim_x: npt.NDArray[np.float64] = field(default_factory=_nan_array)
    sim_v: npt.NDArray[np.float64] = field(default_factory=_nan_array)
    cmd: npt.NDArray[np.float64] = field(default_factory=_nan_array)
    present: npt.NDArray[np.float64] = field(default_factory=_nan_array)
    status: npt.ArrayLike = field(default_factory=_nan_array)
    tick: int = 0
    t_sched: float = 0.0  # s since run start (the show time k·period)
    t_actual: float = 0.0  # s since run start (the clock)
    t_sim_us: float = math.nan
    t_safety_us: float = math.nan
    t_bus_us: float = math.nan
    t_telemetry_us: float = math.nan
    overrun: bool = False
    comm_errors: int = 0  # cumulative
    host_stall_us: float = 0.0
    skipped_ticks: int = 0  # cumulative: ticks caught up without a row before this one
    #: optional: one float64 array of which ``target`` … ``present`` are consecutive views,
    #: in that order (the loop's buffers are): the ring then copies it in one step
    joint_block: npt.NDArray[np.float64] | None = None

    @property
    def lateness_us(self) -> float:
        return (self.t_actual - self.t_sched) * 1e6

    def stacked(self) -> bool:
        """``joint_block`` is set and holds ``target`` … ``present`` as consecutive views,
        in that order (not cheap: the ring checks it once per set of arrays)."""
        b = self.joint_block
        if b is None or b.ndim != 1 or b.dtype != np.float64 or b.strides != (8,) or b.size % 5:
            return False
        n, start = b.size // 5, _address(b)
        fields = (self.target, self.sim_x, self.sim_v, self.cmd, self.present)
        return all(
            isinstance(a, np.ndarray)
            and a.base is b
            and a.shape == (n,)
            and a.strides == (8,)
            and _address(a) == start + 8 * k * n
            for k, a in enumerate(fields)
        )


def _address(a: np.ndarray) -> int:
    address: int = a.__array_interface__["data"][0]
    return address


class TelemetryError(Exception):
    """Base class of the errors raised writing (:mod:`hilsim.telemetry`) or reading
    (:mod:`hilsim.telemetry.reader`) a run directory."""


def csv_columns(joint_names: Sequence[str], version: int = ROWS_SCHEMA_VERSION) -> list[str]:
    """The CSV header for these joints: head, one block per :data:`JOINT_FIELDS` entry, tail
    (of that :data:`ROWS_SCHEMA_VERSION`: the reader reads the older ones too)."""
    names = list(joint_names)
    return [
        *HEAD_COLUMNS,
        *(f"{f}_{j}" for f in JOINT_FIELDS for j in names),
        *TAILS[version],
    ]


def check_joint_names(joint_names: Iterable[str]) -> tuple[str, ...]:
    """The names as a tuple; ``ValueError`` if there are none, if two are equal, or if one cannot be
    a CSV column suffix (empty, padded, or holding a comma, quote or newline)."""
    names = tuple(str(j) for j in joint_names)
    if not names:
        raise ValueError("at least one joint is needed")
    if len(set(names)) != len(names):
        raise ValueError(f"joint names must be unique: {names!r}")
    for j in names:
        if not j or any(c in j for c in ',"\r\n') or j != j.strip():
            raise ValueError(f"joint name {j!r} cannot be a CSV column suffix")
    return names


class TelemetryFormat(StrEnum):
    """The rig's ``telemetry.format``: how the per-tick rows are stored."""

    AUTO = "auto"  # csv for small runs, parquet (else csv.gz) for big ones: choose_format
    CSV = "csv"  # exact text, every float64 round-trips
    CSV_GZ = "csv.gz"  # the same text, gzip-compressed (zcat, pandas, polars, duckdb read it)
    PARQUET = "parquet"  # fixed-point integer columns, delta-encoded, zstd (needs pyarrow)
    NONE = "none"  # no per-tick rows: events.jsonl and summary.json only (summary-only)
    OFF = "off"  # nothing kept: the run directory is removed at the end of the show


#: auto keeps CSV while a 10-minute show's CSV stays under this many bytes (the performance goal)
AUTO_CSV_BYTES_PER_10_MIN = 100e6


def csv_row_bytes(n_joints: int) -> int:
    """An upper estimate of one CSV row's bytes: ~20 per ``%.17g`` float (sign, 17 digits, point,
    comma), 2 per status, the head and tail columns ~122 (measured: 1,751 bytes a row for
    scale16's 16 joints, 430 for the demo's 4)."""
    return 122 + 102 * int(n_joints)


def parquet_available() -> bool:
    """pyarrow can be imported (without importing it)."""
    import importlib.util

    return importlib.util.find_spec("pyarrow") is not None


def choose_format(
    fmt: str, rate_hz: float | None, n_joints: int, *, have_parquet: bool | None = None
) -> tuple[TelemetryFormat, str]:
    """The format a run uses and why (one line, said in the summary and an event).

    ``auto``: CSV while ``600 s * rate_hz * csv_row_bytes(n_joints)`` stays under
    :data:`AUTO_CSV_BYTES_PER_10_MIN` (unknown rate: CSV); above, Parquet when pyarrow is
    installed, else gzip-compressed CSV (3x smaller, still over the goal: the reason says so).
    An explicit ``parquet`` without pyarrow is a ``ValueError`` naming the fix."""
    fmt = TelemetryFormat(fmt)
    have = parquet_available() if have_parquet is None else have_parquet
    if fmt is TelemetryFormat.PARQUET and not have:
        raise ValueError(
            "telemetry.format = \"parquet\" needs pyarrow: pip install 'hilsim[parquet]'"
        )
    if fmt is not TelemetryFormat.AUTO:
        return fmt, "as the rig asks"
    if rate_hz is None:
        return TelemetryFormat.CSV, "auto: rate unknown"
    per_10_min = 600.0 * float(rate_hz) * csv_row_bytes(n_joints)
    size = f"CSV would be ~{per_10_min / 1e6:.0f} MB per 10 min ({n_joints} joints, {rate_hz:g} Hz)"
    if per_10_min <= AUTO_CSV_BYTES_PER_10_MIN:
        return TelemetryFormat.CSV, f"auto: {size}"
    if have:
        return TelemetryFormat.PARQUET, f"auto: {size}"
    return TelemetryFormat.CSV_GZ, (
        f"auto: {size}; pyarrow is not installed, so csv.gz (about a third of that); "
        "pip install 'hilsim[parquet]' for Parquet (about 1/20)"
    )


@dataclass(frozen=True)
class ParquetColumn:
    """One Parquet column: the CSV column it stores, its name, the integer units per CSV unit,
    and its integer type (numpy dtype name)."""

    csv: str
    name: str
    scale: float
    dtype: str


def parquet_columns(
    joint_names: Sequence[str], version: int = ROWS_SCHEMA_VERSION
) -> list[ParquetColumn]:
    """The Parquet columns for these joints, in CSV column order (``docs/telemetry.md``)."""
    out = []
    for c in csv_columns(joint_names, version):
        if c in ("tick", "comm_errors", "skipped_ticks"):
            out.append(ParquetColumn(c, c, 1.0, "int64"))
        elif c == "overrun" or c.startswith("status_"):
            out.append(ParquetColumn(c, c, 1.0, "int8"))
        elif c in ("t_sched", "t_actual"):
            out.append(ParquetColumn(c, c + "_ns", 1e9, "int64"))
        elif c.endswith("_us"):
            out.append(ParquetColumn(c, c[: -len("_us")] + "_ns", 1e3, "int64"))
        elif c.startswith("sim_v_"):
            out.append(ParquetColumn(c, c + "_urad_s", 1e6, "int64"))
        else:  # target, sim_x, cmd, present
            out.append(ParquetColumn(c, c + "_urad", 1e6, "int64"))
    return out
