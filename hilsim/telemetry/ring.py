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

import struct
from operator import attrgetter
from typing import Any

import numpy as np
import numpy.typing as npt

from hilsim.telemetry.format import HEAD_COLUMNS, JOINT_FIELDS, TAIL_FIELDS, TickRecord

#: the arrays :meth:`TickRing.put` last checked (joint block, target, sim_x, sim_v, cmd,
#: present) and a memoryview of the block (None: not stacked). Memoryviews of arrays are
#: taken as ``a.data`` (the same view as ``memoryview(a)``), which numpy's stubs type on
#: Python 3.11 too (they declare ``ndarray.__buffer__`` from 3.12 only).
_StackSeen = tuple[object, object, object, object, object, object, memoryview | None]


class TickRing:
    """``size`` rows of ``n_cols`` floats for ``n_joints`` joints."""

    def __init__(self, size: int, n_joints: int, n_cols: int) -> None:
        if int(size) < 2:
            raise ValueError(f"queue_size must be >= 2, got {size!r}")
        self.size = int(size)
        self.rows = np.full((self.size, n_cols), np.nan)
        base = len(HEAD_COLUMNS)
        n = self.n_joints = n_joints
        self._ncols = n_cols
        self._blocks = tuple(
            (name, slice(base + k * n, base + (k + 1) * n)) for k, name in enumerate(JOINT_FIELDS)
        )
        floats = len(JOINT_FIELDS) - 1  # the blocks before status: one float64 block
        self._floats = (base, base + floats * n)
        self._status_at = base + floats * n
        self._tail_at = base + len(JOINT_FIELDS) * n
        self._tail_of = attrgetter(*TAIL_FIELDS)
        # the loop writes rows through struct packers on the ring's memory (drivers.fill)
        self._bytes = self.rows.data.cast("B")  # memoryview(rows), see _StackSeen
        self._doubles = self._bytes.cast("d")
        self._pack_head = struct.Struct(f"{base}d").pack_into
        self._pack_status = struct.Struct(f"{n}d").pack_into
        self._pack_tail = struct.Struct(f"{len(TAIL_FIELDS)}d").pack_into
        self._pack_late = struct.Struct("5d").pack_into  # stage times, overrun
        self._stack_seen: _StackSeen = (None,) * 6 + (None,)  # arrays last checked, their block
        #: a status array and its values (a memoryview of a uint8 array's, else the array)
        self._status_seen: tuple[object, Any] = (None, None)
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
        head = (self.cursor + 1) >> 1
        at = (head % self.size) * self._ncols  # the row's first double
        self._pack_head(self._bytes, 8 * at, rec.tick, rec.t_sched, rec.t_actual, rec.lateness_us)
        block, seen = rec.joint_block, self._stack_seen
        if (
            seen[0] is not block
            or seen[1] is not rec.target
            or seen[2] is not rec.sim_x
            or seen[3] is not rec.sim_v
            or seen[4] is not rec.cmd
            or seen[5] is not rec.present
        ):
            seen = self._stacked(rec, block)
        view = seen[6]
        if view is not None:
            start, stop = self._floats
            self._doubles[at + start : at + stop] = view
            status = rec.status
            if status is not self._status_seen[0]:
                self._status_values(status)
            self._pack_status(self._bytes, 8 * (at + self._status_at), *self._status_seen[1])
        else:
            row = self.rows[head % self.size]
            for name, cols in self._blocks:
                row[cols] = getattr(rec, name)
        self._pack_tail(self._bytes, 8 * (at + self._tail_at), *self._tail_of(rec))
        self.cursor = (head << 1) | 1

    def _stacked(self, rec: TickRecord, block: np.ndarray | None) -> _StackSeen:
        """Kept for these arrays: whether :meth:`TickRecord.stacked` (worked out once per
        set of arrays; a tick pays six identity checks), and a memoryview of the block."""
        view = None
        if block is not None and rec.stacked() and block.size == 5 * self.n_joints:
            view = block.data  # memoryview(block)
        seen = (block, rec.target, rec.sim_x, rec.sim_v, rec.cmd, rec.present, view)
        self._stack_seen = seen
        return seen

    def _status_values(self, status: npt.ArrayLike) -> None:
        """Kept for this status array: its values as Python ints (a uint8 array's through
        a memoryview)."""
        values: Any = status
        if isinstance(status, np.ndarray) and status.dtype == np.uint8 and status.ndim == 1:
            values = status.data  # memoryview(status)
        self._status_seen = (status, values)

    def amend(self, rec: TickRecord) -> bool:
        """Rewrite the late columns (stage times, overrun) of the pending row if it is
        ``rec.tick``; False if that row was already handed over (or dropped)."""
        cursor = self.cursor
        if not cursor & 1:
            return False
        at = ((cursor >> 1) % self.size) * self._ncols
        if self._doubles[at] != rec.tick:
            return False
        self._pack_late(
            self._bytes,
            8 * (at + self._tail_at),
            rec.t_sim_us,
            rec.t_safety_us,
            rec.t_bus_us,
            rec.t_telemetry_us,
            rec.overrun,
        )
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
        rows: list[list[float]] = self.rows[start : start + count].tolist()
        self.tail += count
        return rows

    def take_array(self, max_rows: int) -> np.ndarray:
        """:meth:`take` as a float64 array (a copy), for sinks that work on columns."""
        start = self.tail % self.size
        count = min(self.pending(), max_rows, self.size - start)
        rows = self.rows[start : start + count].copy()
        self.tail += count
        return rows
