"""The run directory's format, shared by the writer and the reader: file names, CSV columns.

A run directory (written by :class:`hilsim.telemetry.TelemetryWriter`, read back by
:func:`hilsim.telemetry.reader.read_run`) holds::

    telemetry.csv    one row per tick (columns below), header on the first line; or, per
                     the rig's ``telemetry.format`` (:class:`TelemetryFormat`), the same text
                     gzip-compressed (``telemetry.csv.gz``), or Parquet part files
                     (``telemetry.parquet/part-NNNNN.parquet``, columns :func:`parquet_columns`)
    events.jsonl     one JSON object per line: start/stop, faults, warnings, signals, dropped rows
    summary.json     written once by :meth:`TelemetryWriter.close` (absent if the process died)
    rig.toml         a verbatim copy of the rig config text the loop passed (``config_text``)

**CSV columns** (:func:`csv_columns`), grouped by quantity, joints in the order given::

    tick                       tick number (int, from 0)
    t_sched                    scheduled tick time, s since run start
    t_actual                   time the tick started, s since run start
    lateness_us                (t_actual - t_sched) * 1e6, µs
    target_<j>  ...            animation target, rad              (one column per joint j, then the
    sim_x_<j>   ...            spring position, rad                next quantity for every joint)
    sim_v_<j>   ...            spring velocity, rad/s
    cmd_<j>     ...            commanded position after safety, rad
    present_<j> ...            present position read back, rad; ``nan`` when there was no valid read
    status_<j>  ...            read status (:class:`drivers.servo_bus.ReadStatus`: 0 OK, 1 STALE,
                               2 ERROR, 3 ALERT)
    t_sim_us  t_safety_us  t_bus_us  t_telemetry_us    per-stage wall time of this tick, µs:
                               sim: the reading mapped to joints, live inputs and cues, the
                               targets sampled, the read and following checks, the springs
                               stepped to the next tick; safety: the filter (its event, if
                               any), the commands mapped to servo ticks; bus: the Sync Write
                               and Sync Read, and the servo checks after a bus silence (health
                               reads, recoveries, their events); telemetry: the host-stall
                               accounting, the row recorded. In no stage: a health read in the
                               spare time, the catch-up after an overrun, the wait
    overrun                    1 if the tick missed its deadline, else 0
    comm_errors                cumulative communication errors on the bus
    host_stall_us              time the host itself stalled in or before this tick (the process
                               was not running: a GC pause, a busy neighbour, SIGSTOP), µs;
                               0 on a healthy tick. A tick with a stall is "host-late": its read
                               failures are not blamed on a servo.

Times, targets, spring state, commands and present positions are written with ``%.17g`` (every
float64 round-trips exactly); µs columns with ``%.3f`` (ns resolution); integer columns as integers;
a value never given is ``nan``. ``telemetry.csv.gz`` holds exactly that text.

**Parquet** (big runs; needs pyarrow, ``pip install 'hilsim[parquet]'``): the same columns as
integers in a unit that says their precision, named with it (:func:`parquet_columns`): times in
ns (``t_sched_ns``, ``t_actual_ns``, ``lateness_ns``, ``t_<stage>_ns``, ``host_stall_ns``),
angles in µrad (``target_<j>_urad``, ``sim_x_``, ``cmd_``, ``present_``; 1 µrad is 1/1534 of a
servo tick), velocities in µrad/s (``sim_v_<j>_urad_s``); ``tick``, ``status_<j>``, ``overrun``,
``comm_errors`` as they are. NaN is null; +-inf (and beyond +-2**62 units) is +-(2**63 - 1).
A part is written whole (temporary name, fsync, rename) at each fsync point of the writer, so a
crash or power cut leaves only complete parts: what was fsync-ed is readable.

:class:`TelemetryError` is the base of the errors raised writing or reading a run directory.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

TELEMETRY_CSV = "telemetry.csv"
TELEMETRY_CSV_GZ = "telemetry.csv.gz"
TELEMETRY_PARQUET = "telemetry.parquet"  # a directory of part files
EVENTS_JSONL = "events.jsonl"
SUMMARY_JSON = "summary.json"
CONFIG_NAME = "rig.toml"
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
)

#: the TickRecord attributes behind TAIL_COLUMNS, in column order
TAIL_FIELDS: tuple[str, ...] = (
    *(f"t_{s}_us" for s in STAGES),
    "overrun",
    "comm_errors",
    "host_stall_us",
)


def _nan_array() -> npt.NDArray[np.float64]:
    return np.full(0, math.nan)


@dataclass(slots=True, eq=False)
class TickRecord:
    """One tick's row, filled in place by the loop and handed to ``TelemetryWriter.record``.

    The loop makes one and keeps it: the array fields are *its own buffers* (referenced, not
    copied; ``record`` copies them into the ring), the scalars are overwritten each tick. Each
    attribute is one CSV column or one block of per-joint columns (names as in the module
    docstring; ``target`` … ``status`` are the :data:`JOINT_FIELDS`). Stage times not known
    yet are NaN; :meth:`TelemetryWriter.amend` writes the late ones (``t_sim_us``,
    ``t_telemetry_us``, ``overrun``) once the tick is over.
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


def csv_columns(joint_names: Sequence[str]) -> list[str]:
    """The CSV header for these joints: head, one block per :data:`JOINT_FIELDS` entry, tail."""
    names = list(joint_names)
    return [
        *HEAD_COLUMNS,
        *(f"{f}_{j}" for f in JOINT_FIELDS for j in names),
        *TAIL_COLUMNS,
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


#: auto keeps CSV while a 10-minute show's CSV stays under this many bytes (issue 12's goal)
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


def parquet_columns(joint_names: Sequence[str]) -> list[ParquetColumn]:
    """The Parquet columns for these joints, in CSV column order (see the module docstring)."""
    out = []
    for c in csv_columns(joint_names):
        if c in ("tick", "comm_errors"):
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
