"""CSV animations: a file with a time column and one column of degrees per joint, as tracks.

:meth:`CsvAnimation.load` reads and checks a file once (errors are :class:`CsvFormatError`, with
``file:line:``); :meth:`CsvAnimation.curve` gives one column as a :class:`CsvCurve`, a
:class:`~hilsim.targets.Track` that interpolates linearly between rows and holds before and after.
Rig files reach these through :func:`hilsim.targets.track_from_spec` (``type = "csv"``).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray
from hilsim.targets.formats.common import SampledTrack
from hilsim.targets.tracks import MAX_TRACK_DEG, MAX_TRACK_TURNS, frozen_array

#: header names accepted for the CSV time column (case-insensitive)
TIME_COLUMNS = ("time_s", "time", "t")


class CsvFormatError(ValueError):
    """A CSV animation that cannot be used; the message starts with ``file:line:``."""

    def __init__(self, path: str | Path, line: int, message: str) -> None:
        super().__init__(f"{path}:{line}: {message}")
        self.path, self.line = str(path), line


@dataclass(frozen=True, eq=False, init=False)
class CsvCurve(SampledTrack):
    """One joint's column of a CSV animation: linear between rows, held before and after
    (a :class:`~hilsim.targets.formats.common.SampledTrack`, ``interpolation="linear"``).

    Args:
        times_s: row times, shape ``(k,)``, finite, strictly increasing (s).
        values_rad: the column, shape ``(k,)``, finite (rad).
        source: where it came from, for messages (e.g. ``"demo_animation.csv:jaw"``).

    The velocity is the slope of the segment t lies in (at a row: the segment that starts there).
    Kept lean (two lists and the slopes, no per-segment objects) because a show-length CSV has
    thousands of rows per joint.
    """

    def __init__(
        self,
        times_s: npt.ArrayLike,
        values_rad: npt.ArrayLike,
        interpolation: str = "linear",
        source: str = "",
    ) -> None:
        super().__init__(times_s, values_rad, interpolation, source)


@dataclass(frozen=True, eq=False)
class CsvAnimation:
    """A CSV animation file, loaded once: a time column (s) and one column per joint (degrees).

    Format: a header row, then one row per sample. The first column is the time in seconds, headed
    ``time_s`` (or ``time``, ``t``); the others are named after joints and hold degrees. Blank lines
    and lines starting with ``#`` are skipped. Times must strictly increase; every cell must be a
    finite number. ``columns`` maps each joint name to its values in radians, shape ``(k,)``.
    """

    path: Path
    times_s: FloatArray
    columns: Mapping[str, FloatArray]

    @classmethod
    def load(cls, path: str | Path) -> CsvAnimation:
        """Read and check the file.

        Raises:
            CsvFormatError: ``file:line: ...`` for a bad header, cell, row length or time, or
                bytes that are not UTF-8 text (a binary file).
            OSError: the file cannot be read.
        """
        path = Path(path)
        header: list[str] | None = None
        rows: list[list[float]] = []
        prev_line = 0
        raw = path.read_bytes()
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            line = raw.count(b"\n", 0, exc.start) + 1
            raise CsvFormatError(
                path,
                line,
                f"not a text file: byte {raw[exc.start]:#04x} is not UTF-8 "
                "(a CSV animation is text: time_s,joint,... then one row per sample)",
            ) from None
        if "\0" in text:
            line = text.count("\n", 0, text.index("\0")) + 1
            raise CsvFormatError(path, line, "not a text file: it contains NUL bytes")
        reader = csv.reader(io.StringIO(text, newline=""))
        try:
            for row in reader:
                line = reader.line_num
                if not any(c.strip() for c in row) or row[0].lstrip().startswith("#"):
                    continue
                if header is None:
                    header = _csv_header(path, line, row)
                    continue
                if len(row) != len(header):
                    raise CsvFormatError(
                        path, line, f"{len(row)} cells, but the header has {len(header)}"
                    )
                values = [
                    _csv_number(path, line, name, cell, degrees=j > 0)
                    for j, (name, cell) in enumerate(zip(header, row, strict=True))
                ]
                if rows and values[0] <= rows[-1][0]:
                    raise CsvFormatError(
                        path,
                        line,
                        f"time {values[0]!r} s is not after {rows[-1][0]!r} s on line {prev_line}",
                    )
                rows.append(values)
                prev_line = line
        except csv.Error as exc:  # e.g. a field beyond csv.field_size_limit()
            raise CsvFormatError(path, reader.line_num, f"not a readable CSV: {exc}") from None

        if header is None:
            raise CsvFormatError(path, 1, "no header row (expected e.g. 'time_s,jaw,tail')")
        if not rows:
            raise CsvFormatError(path, 2, "no data rows after the header")
        data = np.array(rows, dtype=np.float64)
        columns = {name: frozen_array(np.radians(data[:, j])) for j, name in enumerate(header) if j}
        return cls(path=path, times_s=frozen_array(data[:, 0]), columns=MappingProxyType(columns))

    @property
    def names(self) -> tuple[str, ...]:
        """The joint columns, in file order."""
        return tuple(self.columns)

    @property
    def duration(self) -> float:
        """Time of the last row (s)."""
        return float(self.times_s[-1])

    def curve(self, column: str, interpolation: str = "linear") -> CsvCurve:
        """The track of one column, joined linearly between rows or each row ``"hold"`` until
        the next. Raises :class:`CsvFormatError` (line 1) if there is none."""
        if column not in self.columns:
            raise CsvFormatError(
                self.path, 1, f"no column {column!r}; the joint columns are {', '.join(self.names)}"
            )
        values, source = self.columns[column], f"{self.path}:{column}"
        return CsvCurve(self.times_s, values, interpolation, source=source)


def _csv_header(path: Path, line: int, row: list[str]) -> list[str]:
    names = [c.strip() for c in row]
    if names[0].lower() not in TIME_COLUMNS:
        raise CsvFormatError(
            path, line, f"the first column must be the time in seconds, headed 'time_s', "
            f"got {names[0]!r}"
        )  # fmt: skip
    if len(names) < 2:
        raise CsvFormatError(path, line, "no joint columns after the time column")
    seen: set[str] = set()
    for name in names[1:]:
        if not name:
            raise CsvFormatError(path, line, "a joint column has an empty name")
        if name in seen:
            raise CsvFormatError(path, line, f"column {name!r} appears twice")
        seen.add(name)
    return names


def _csv_number(path: Path, line: int, name: str, cell: str, degrees: bool) -> float:
    try:
        x = float(cell)
    except ValueError:
        raise CsvFormatError(
            path, line, f"column {name!r}: {cell.strip()!r} is not a number"
        ) from None
    if not math.isfinite(x):
        raise CsvFormatError(path, line, f"column {name!r}: {cell.strip()!r} is not finite")
    if degrees and abs(x) > MAX_TRACK_DEG:  # a joint's column (the time's bound is its own)
        raise CsvFormatError(
            path,
            line,
            f"column {name!r}: {cell.strip()}° is beyond ±{MAX_TRACK_DEG}° "
            f"({MAX_TRACK_TURNS} turns)",
        )
    return x
