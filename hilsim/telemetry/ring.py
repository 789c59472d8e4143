"""The lock-free ring of tick rows between the loop thread and the telemetry writer thread.

One row per tick, a float64 array shaped like the CSV (:func:`~hilsim.telemetry.format.
csv_columns`). Single producer (the loop: :meth:`TickRing.put`, :meth:`TickRing.amend`),
single consumer (the writer: :meth:`TickRing.take`). No lock: the loop only moves
``cursor``, the writer only ``tail``, and CPython's GIL orders the row stores before the
cursor store.

``cursor`` is ``2 · rows handed over + 1`` if the next slot holds a complete row not yet
handed over — the one :meth:`amend` may still change. One int, so a single store both
publishes the previous row and marks the new one pending; a row interrupted half-written
(a signal handler closing the writer) is never handed over.
"""

from __future__ import annotations

import numpy as np

from hilsim.telemetry.format import HEAD_COLUMNS, JOINT_FIELDS, TAIL_FIELDS, TickRecord


class TickRing:
    """``size`` rows of ``n_cols`` floats for ``n_joints`` joints."""

    def __init__(self, size: int, n_joints: int, n_cols: int) -> None:
        if int(size) < 2:
            raise ValueError(f"queue_size must be >= 2, got {size!r}")
        self.size = int(size)
        self.rows = np.full((self.size, n_cols), np.nan)
        base = len(HEAD_COLUMNS)
        n = n_joints
        self._blocks = tuple(
            (name, slice(base + k * n, base + (k + 1) * n)) for k, name in enumerate(JOINT_FIELDS)
        )
        self._tail_at = base + len(JOINT_FIELDS) * n
        self.cursor = 0  # the loop's
        self.tail = 0  # the writer's: rows copied out

    # ------------------------------------------------------------------ the loop's side
    @property
    def head(self) -> int:
        """Rows recorded (the slot the next row goes to)."""
        return (self.cursor + 1) >> 1

    def handed_over(self) -> int:
        return self.cursor >> 1

    def full(self) -> bool:
        return self.head - self.tail >= self.size

    def publish_pending(self) -> None:
        """Hand the pending row (if any) to the writer: it can no longer be amended."""
        cursor = self.cursor
        if cursor & 1:
            self.cursor = cursor + 1

    def put(self, rec: TickRecord) -> None:
        """Copy ``rec`` into the next slot (the caller checked :meth:`full`); it becomes the
        pending row and the previous one is handed over."""
        head = self.head
        row = self.rows[head % self.size]
        row[0] = rec.tick
        row[1] = rec.t_sched
        row[2] = rec.t_actual
        row[3] = rec.lateness_us
        for name, cols in self._blocks:
            row[cols] = getattr(rec, name)
        k = self._tail_at
        for j, name in enumerate(TAIL_FIELDS):
            row[k + j] = getattr(rec, name)
        self.cursor = (head << 1) | 1

    def amend(self, rec: TickRecord) -> bool:
        """Rewrite the late columns (stage times, overrun) of the pending row if it is
        ``rec.tick``; False if that row was already handed over (or dropped)."""
        cursor = self.cursor
        if not cursor & 1:
            return False
        row = self.rows[(cursor >> 1) % self.size]
        if row[0] != rec.tick:
            return False
        k = self._tail_at
        row[k] = rec.t_sim_us
        row[k + 1] = rec.t_safety_us
        row[k + 2] = rec.t_bus_us
        row[k + 3] = rec.t_telemetry_us
        row[k + 4] = rec.overrun
        return True

    # ------------------------------------------------------------------ the writer's side
    def pending(self) -> int:
        """Rows handed over and not yet taken."""
        return (self.cursor >> 1) - self.tail

    def take(self, max_rows: int) -> list[list[float]]:
        """Copy out up to ``max_rows`` handed-over rows (never across the wrap); their slots
        are free once this returns."""
        start = self.tail % self.size
        count = min(self.pending(), max_rows, self.size - start)
        rows = self.rows[start : start + count].tolist()
        self.tail += count
        return rows
