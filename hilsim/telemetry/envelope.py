"""A run's rows in bounded memory: streamed, and kept as a min/max envelope per bucket of ticks.

:class:`Envelope` takes the rows a chunk at a time (:func:`hilsim.telemetry.reader.read_run`
with ``max_rows``). Up to ``max_rows`` rows it keeps them as they are; past that it keeps, per
bucket of consecutive rows, each column's minimum and maximum (NaN ignored), and halves the
number of buckets (merging neighbours) whenever it passes ``2 * buckets``, so an hour or a week
of rows takes the same memory. What a plot needs beyond the envelope is counted exactly, per
bucket: rows, overruns, reads of each non-OK status per joint, ticks where the command differs
from the spring per joint (the safety filter acted), and the sum of each stage's time (for
exact means); and over the whole run a log histogram of lateness and of each stage's time
(percentiles to within 2.3 %: :meth:`Envelope.percentile`).

The rows come out (:meth:`Envelope.columns`) as two per bucket: its minima at the bucket's first
``t_sched``, its maxima at its last, so a line drawn through them covers everything the bucket
held.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilsim.telemetry.format import STAGES

#: histogram bins: 100 per decade from 1e-3 to 1e8 µs (a bin is 2.3 % wide); zero and below
#: (a virtual clock's lateness) count in the first bin, beyond the range in the last
_DECADES = (-3, 8)
_PER_DECADE = 100
EDGES = np.logspace(_DECADES[0], _DECADES[1], (_DECADES[1] - _DECADES[0]) * _PER_DECADE + 1)
#: |cmd - sim_x| above this is "the filter acted" (as in hilsim.telemetry.joint_plots)
ACTED_TOLERANCE_RAD = 1e-9
#: the derived column: the sum of a tick's stage times, µs (its bucket maximum: the worst tick)
STAGE_TOTAL = "t_total_us"
#: the read statuses counted per joint (drivers.servo_bus.ReadStatus: STALE, ERROR, ALERT)
BAD_STATUSES = (1, 2, 3)


@dataclass(eq=False)
class Envelope:
    """The accumulator (module docstring). ``names``: the CSV columns, in row order;
    ``joints``: the joint names; ``max_rows``: rows kept as they are before bucketing;
    ``buckets``: about how many buckets are kept after (between it and twice it)."""

    names: list[str]
    joints: tuple[str, ...]
    max_rows: int = 200_000
    buckets: int = 4096
    rows: int = 0
    width: int = 1  # rows per bucket while bucketing (the last bucket may be part filled)
    lo: list[np.ndarray] = field(default_factory=list)
    hi: list[np.ndarray] = field(default_factory=list)
    counts: list[np.ndarray] = field(default_factory=list)
    hist: dict[str, np.ndarray] = field(default_factory=dict)
    #: the counts per output row, once read (:meth:`columns`' second half)
    counted: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._stage_cols = [self.names.index(f"t_{s}_us") for s in STAGES]
        self.names = [*self.names, STAGE_TOTAL]  # a derived column: its max is the worst tick
        at = {n: k for k, n in enumerate(self.names)}
        self._at = at
        self._status = [at[f"status_{j}"] for j in self.joints]
        self._cmd = [at[f"cmd_{j}"] for j in self.joints]
        self._simx = [at[f"sim_x_{j}"] for j in self.joints]
        self._stages = [at[f"t_{s}_us"] for s in STAGES]
        #: the counted columns: rows, overruns, bad reads per status and joint, acted per joint,
        #: each stage's time summed and its finite rows
        self.count_names = [
            "rows",
            "overrun",
            *(f"status{c}_{j}" for c in BAD_STATUSES for j in self.joints),
            *(f"acted_{j}" for j in self.joints),
            *(f"sum_t_{s}_us" for s in STAGES),
            *(f"n_t_{s}_us" for s in STAGES),
        ]
        self.hist = {n: np.zeros(EDGES.size, np.int64) for n in ("lateness_us", *self._stage_names)}
        self._tail: np.ndarray | None = None  # rows not yet a whole bucket

    @property
    def _stage_names(self) -> list[str]:
        return [f"t_{s}_us" for s in STAGES]

    @property
    def decimated(self) -> bool:
        return self.width > 1

    def add(self, rows: np.ndarray) -> None:
        """Take a chunk of rows (``(n, len(names))`` float64, in tick order)."""
        if not rows.size:
            return
        with np.errstate(invalid="ignore"):
            total = np.nansum(rows[:, self._stage_cols], axis=1)
        rows = np.column_stack([rows, total])
        self.rows += len(rows)
        for name in self.hist:
            vals = rows[:, self._at[name]]
            vals = vals[np.isfinite(vals)]
            idx = np.clip(np.searchsorted(EDGES, vals, side="left"), 0, EDGES.size - 1)
            self.hist[name] += np.bincount(idx, minlength=EDGES.size)
        if self._tail is not None:
            rows = np.concatenate([self._tail, rows])
            self._tail = None
        whole = len(rows) - len(rows) % self.width
        if whole < len(rows):
            self._tail = rows[whole:].copy()
        if whole:
            self._bucket(rows[:whole])
        self._shrink()

    def _row_counts(self, rows: np.ndarray) -> np.ndarray:
        """The counted columns of each row (``count_names``)."""
        out = np.zeros((len(rows), len(self.count_names)))
        out[:, 0] = 1.0
        out[:, 1] = rows[:, self._at["overrun"]] != 0
        k = 2
        for code in BAD_STATUSES:
            for col in self._status:
                out[:, k] = rows[:, col] == code
                k += 1
        with np.errstate(invalid="ignore"):
            for cmd, simx in zip(self._cmd, self._simx, strict=True):
                out[:, k] = np.abs(rows[:, cmd] - rows[:, simx]) > ACTED_TOLERANCE_RAD
                k += 1
        stages = rows[:, self._stages]
        finite = np.isfinite(stages)
        out[:, k : k + len(STAGES)] = np.where(finite, stages, 0.0)
        out[:, k + len(STAGES) :] = finite
        return out

    def _bucket(self, rows: np.ndarray) -> None:
        w, ncols = self.width, rows.shape[1]
        if w == 1:  # rows kept as they are: counted only if they come to be bucketed
            self.lo.append(rows)
            self.hi.append(rows)  # the same array: no copy while rows are kept as they are
            return
        counts = self._row_counts(rows)
        shaped = rows.reshape(-1, w, ncols)
        with np.errstate(invalid="ignore"):
            self.lo.append(np.fmin.reduce(shaped, axis=1))
            self.hi.append(np.fmax.reduce(shaped, axis=1))
        self.counts.append(counts.reshape(-1, w, counts.shape[1]).sum(axis=1))

    def _n_buckets(self) -> int:
        return sum(len(a) for a in self.lo)

    def _shrink(self) -> None:
        """Merge neighbouring buckets while there are too many (module docstring)."""
        limit = self.max_rows if self.width == 1 else 2 * min(self.buckets, self.max_rows // 2)
        if self._n_buckets() <= limit:
            return
        if self.width == 1:  # the rows kept so far: counted now, once
            self.lo = self.hi = [np.concatenate(self.lo)]
            self.counts = [self._row_counts(self.lo[0])]
        lo, hi, counts = (np.concatenate(a) for a in (self.lo, self.hi, self.counts))
        target = max(1, min(self.buckets, self.max_rows // 2))
        while len(lo) > target:
            even = len(lo) - len(lo) % 2
            with np.errstate(invalid="ignore"):
                lo = (
                    np.fmin(lo[0:even:2], lo[1:even:2])
                    if even == len(lo)
                    else np.concatenate([np.fmin(lo[0:even:2], lo[1:even:2]), lo[even:]])
                )
                hi = (
                    np.fmax(hi[0:even:2], hi[1:even:2])
                    if even == len(hi)
                    else np.concatenate([np.fmax(hi[0:even:2], hi[1:even:2]), hi[even:]])
                )
            merged = counts[0:even:2] + counts[1:even:2]
            counts = merged if even == len(counts) else np.concatenate([merged, counts[even:]])
            self.width *= 2
        self.lo, self.hi, self.counts = [lo], [hi], [counts]

    def finish(self) -> None:
        """The last, part-filled bucket."""
        tail, self._tail = self._tail, None
        if tail is not None and len(tail):
            counts = self._row_counts(tail).sum(axis=0, keepdims=True)
            with np.errstate(invalid="ignore"):
                self.lo.append(np.fmin.reduce(tail, axis=0, keepdims=True))
                self.hi.append(np.fmax.reduce(tail, axis=0, keepdims=True))
            self.counts.append(counts)

    def columns(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """The rows (CSV columns; two a bucket when decimated) and, when decimated, the counts
        per output row (``count_names``; a bucket's counts on its first row, zeros on its
        second); rows kept as they are have no counts (empty)."""
        ncols = len(self.names)
        if not self.decimated:  # the rows as they are: nothing counted (the rows say it)
            rows = _stacked(self.lo, ncols)
            self.lo = self.hi = [rows]
            return {n: rows[:, k] for k, n in enumerate(self.names)}, {}
        lo, hi, counts = (np.concatenate(a) for a in (self.lo, self.hi, self.counts))
        self.lo, self.hi, self.counts = [lo], [hi], [counts]
        rows = np.empty((2 * len(lo), ncols), order="F")  # a column is contiguous: no copies
        rows[0::2], rows[1::2] = lo, hi
        per_row = np.zeros((2 * len(lo), counts.shape[1]), order="F")
        per_row[0::2] = counts
        return (
            {n: rows[:, k] for k, n in enumerate(self.names)},
            {n: per_row[:, k] for k, n in enumerate(self.count_names)},
        )

    def percentile(self, name: str, q: float) -> float:
        """The ``q``-th percentile of a histogrammed column over the whole run (the upper edge
        of its bin: within 2.3 % above the value); NaN when it has no values."""
        h = self.hist[name]
        total = int(h.sum())
        if total == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(h), q / 100.0 * total, side="left"))
        return float(EDGES[min(k, EDGES.size - 1)]) if k > 0 else 0.0


def _stacked(chunks: list[np.ndarray], ncols: int) -> np.ndarray:
    """The chunks as one array in column order (a column is a contiguous view)."""
    out = np.empty((sum(len(c) for c in chunks), ncols), order="F")
    at = 0
    for c in chunks:
        out[at : at + len(c)] = c
        at += len(c)
    return out
