"""Reading a run back: :func:`read_run` loads a run directory into a :class:`Run`.

The directory's format is in :mod:`hilsim.telemetry.format`. A run being written, or cut short by
a crash, still loads: what was tolerated is listed in ``Run.warnings``.
"""

from __future__ import annotations

import json
import math
import os
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
    SUMMARY_JSON,
    TAIL_COLUMNS,
    TELEMETRY_CSV,
    TelemetryError,
    csv_columns,
)


class NotARunError(TelemetryError, FileNotFoundError):
    """The directory holds no ``telemetry.csv``."""


class RunFormatError(TelemetryError, ValueError):
    """``telemetry.csv`` does not start with a telemetry header."""


@dataclass(eq=False)
class Run:
    """One run directory, loaded. Columns are float64 arrays shaped ``(ticks,)`` by CSV name.

    ``warnings`` lists what was tolerated: a truncated last line (crash mid-write), unparsable
    lines, tick gaps (dropped rows), a missing or corrupt summary. ``truncated`` is True when the
    CSV's last line was cut off.
    """

    path: Path
    joint_names: tuple[str, ...]
    columns: dict[str, np.ndarray]
    events: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    config_text: str | None = None
    warnings: list[str] = field(default_factory=list)
    truncated: bool = False

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
        return self.columns["overrun"] != 0

    @property
    def comm_errors(self) -> np.ndarray:
        return self.columns["comm_errors"].astype(np.int64)

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


def _parse_header(line: str) -> tuple[list[str], tuple[str, ...]]:
    names = line.rstrip("\r\n").split(",")
    head, tail = len(HEAD_COLUMNS), len(TAIL_COLUMNS)
    middle = names[head : len(names) - tail]
    ok = (
        len(names) >= head + tail + len(JOINT_FIELDS)
        and tuple(names[:head]) == HEAD_COLUMNS
        and tuple(names[len(names) - tail :]) == TAIL_COLUMNS
        and len(middle) % len(JOINT_FIELDS) == 0
    )
    if ok:
        n = len(middle) // len(JOINT_FIELDS)
        prefix = JOINT_FIELDS[0] + "_"
        joints = tuple(c[len(prefix) :] for c in middle[:n])
        ok = (
            all(c.startswith(prefix) for c in middle[:n])
            and middle == csv_columns(joints)[head : len(names) - tail]
        )
        if ok:
            return names, joints
    raise RunFormatError(f"not a telemetry header: {line[:120]!r}")


def _parse_rows(lines: list[str], ncols: int, warnings: list[str]) -> np.ndarray:
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
        warnings.append(f"{TELEMETRY_CSV}: skipped {len(bad)} unparsable line(s): {shown}")
    return np.array(rows, dtype=np.float64).reshape(-1, ncols)


def _read_lines(path: Path, warnings: list[str]) -> tuple[list[str], bool]:
    """Complete lines of a text file; a cut-off last line (or NUL tail) is dropped and reported."""
    data = path.read_bytes().rstrip(b"\x00")
    text = data.decode("utf-8", errors="replace")
    lines = text.split("\n")
    partial = lines.pop()  # "" when the file ends with a newline
    if partial:
        warnings.append(
            f"{path.name}: last line is incomplete ({len(partial)} chars, "
            "the run probably ended abruptly); ignored"
        )
    return [ln for ln in lines if ln.strip()], bool(partial)


def read_run(run_dir: str | os.PathLike[str]) -> Run:
    """Load a run directory written by :class:`TelemetryWriter` (possibly while it is written,
    or after a crash). Raises :class:`NotARunError` if there is no ``telemetry.csv`` and
    :class:`RunFormatError` if its header is not a telemetry header; everything else that is
    wrong is tolerated and listed in ``Run.warnings``."""
    path = Path(run_dir)
    csv_path = path / TELEMETRY_CSV
    if not csv_path.is_file():
        raise NotARunError(f"{path} is not a run directory (no {TELEMETRY_CSV})")
    warnings: list[str] = []
    lines, truncated = _read_lines(csv_path, warnings)
    if not lines:
        raise RunFormatError(f"{csv_path} has no header")
    names, joints = _parse_header(lines[0])
    data = _parse_rows(lines[1:], len(names), warnings)
    columns = {name: data[:, k].copy() for k, name in enumerate(names)}

    tick = columns["tick"]
    missing = 0
    if tick.size > 1:
        steps = np.diff(tick)
        missing = int(np.sum(steps[steps > 1] - 1))
        if np.any(steps < 1):
            warnings.append(f"{TELEMETRY_CSV}: tick numbers are not increasing")

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
    if missing:
        # ticks the loop caught up on after an overrun have no row (nothing was sent or read)
        loop = (summary or {}).get("loop") or {}
        skipped = loop.get("skipped_ticks") if isinstance(loop, dict) else None
        dropped = missing - skipped if isinstance(skipped, int) else missing
        if isinstance(skipped, int) and skipped:
            warnings.append(
                f"{TELEMETRY_CSV}: {min(skipped, missing)} tick(s) skipped by the loop "
                "(simulated without bus traffic to catch up after overruns)"
            )
        if dropped > 0:
            warnings.append(f"{TELEMETRY_CSV}: {dropped} tick(s) missing (rows dropped?)")
    tel = summary.get("telemetry") if summary else None
    if isinstance(tel, dict):
        if tel.get("rows_dropped"):
            warnings.append(f"{tel['rows_dropped']} row(s) dropped while recording (disk stalled)")
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
    )
