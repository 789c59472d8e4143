"""The run's rows under a size and age cap: parts, and which to remove, oldest first.

A sink under a cap (``telemetry.max_mb``, ``telemetry.max_age_h``) writes its rows in parts
(``telemetry.parts/part-NNNNN.csv[.gz]``, or Parquet's ``telemetry.parquet/part-NNNNN.parquet``)
and tells a :class:`PartBook` of each part it closes. Before a part is started the book removes
the oldest closed parts until the closed ones and a whole new part fit under the size cap, so
the rows on the disk never exceed it; parts whose newest row is older than the age cap go too.
Each removal is one note (a ``telemetry_rotated`` event for ``events.jsonl``, written by the
writer thread) and is counted (:meth:`PartBook.summary`, the summary's ``telemetry.rotation``).
Everything here runs on the writer thread.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: a part is this fraction of the size cap: the rows kept are between about 70 % of it (room
#: is made for a whole part and its overshoot) and all of it
PART_FRACTION = 1 / 8
#: a part is closed at the latest after this fraction of the age cap
AGE_FRACTION = 1 / 8


@dataclass
class Part:
    """One closed part: its file, size, rows, first and last tick, and when it was closed."""

    path: Path
    size: int
    rows: int
    first_tick: int
    last_tick: int
    closed_at: float  # time.time()


class PartBook:
    """The closed parts of a run's rows and the caps they are kept under (module docstring).

    ``max_bytes``/``max_age_s``: the caps (None: no cap). :attr:`part_bytes` and
    :attr:`part_age_s` say when the sink closes its part. :attr:`notes` holds the events not yet
    written (the writer thread takes them)."""

    def __init__(self, max_bytes: int | None, max_age_s: float | None) -> None:
        self.max_bytes = max_bytes
        self.max_age_s = max_age_s
        self.part_bytes = None if max_bytes is None else max(1, int(max_bytes * PART_FRACTION))
        self.part_age_s = None if max_age_s is None else max_age_s * AGE_FRACTION
        self.parts: deque[Part] = deque()
        self.notes: list[dict[str, Any]] = []
        self.parts_removed = self.rows_removed = self.bytes_removed = 0
        self.first_tick_kept: int | None = None

    def full(self, size: int, opened_at: float, now: float) -> bool:
        """Whether the part being written (``size`` bytes, opened at monotonic ``opened_at``)
        should be closed now."""
        if self.part_bytes is not None and size >= self.part_bytes:
            return True
        return self.part_age_s is not None and now - opened_at >= self.part_age_s

    def closed(self, part: Part) -> None:
        self.parts.append(part)
        if self.first_tick_kept is None:
            self.first_tick_kept = part.first_tick

    def make_room(self, next_bytes: int) -> None:
        """Remove the oldest parts until the closed ones and ``next_bytes`` more fit under the
        size cap, and those older than the age cap."""
        now = time.time()
        while self.parts and self.max_age_s is not None:
            if now - self.parts[0].closed_at <= self.max_age_s:
                break
            self._remove("age")
        if self.max_bytes is None:
            return
        held = sum(p.size for p in self.parts)
        while self.parts and held + next_bytes > self.max_bytes:
            held -= self.parts[0].size
            self._remove("size")

    def _remove(self, why: str) -> None:
        part = self.parts.popleft()
        with contextlib.suppress(FileNotFoundError):
            part.path.unlink()
        self.parts_removed += 1
        self.rows_removed += part.rows
        self.bytes_removed += part.size
        self.first_tick_kept = self.parts[0].first_tick if self.parts else part.last_tick + 1
        cap = (
            f"telemetry.max_mb = {self.max_bytes / 1e6:g}"
            if why == "size" and self.max_bytes is not None
            else f"telemetry.max_age_h = {(self.max_age_s or 0.0) / 3600:g}"
        )
        self.notes.append(
            {
                "tick": part.last_tick,
                "t": None,
                "wall": time.time(),
                "kind": "telemetry_rotated",
                "message": f"{cap}: removed the oldest part {part.path.name} "
                f"({part.size / 1e6:.1f} MB, ticks {part.first_tick}-{part.last_tick}); "
                f"{self.parts_removed} part(s), {self.rows_removed} row(s) removed so far",
                "why": why,
                "part": part.path.name,
                "bytes": part.size,
                "rows": part.rows,
                "first_tick": part.first_tick,
                "last_tick": part.last_tick,
            }
        )

    def take_notes(self) -> list[dict[str, Any]]:
        notes, self.notes = self.notes, []
        return notes

    def summary(self) -> dict[str, Any]:
        """The summary's ``telemetry.rotation``: the caps and what they removed."""
        return {
            "max_bytes": self.max_bytes,
            "max_age_s": self.max_age_s,
            "parts_removed": self.parts_removed,
            "rows_removed": self.rows_removed,
            "bytes_removed": self.bytes_removed,
            "first_tick_kept": self.first_tick_kept if self.parts_removed else 0,
        }
