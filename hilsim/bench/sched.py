"""Loop timing: the tick scheduler alone, against absolute deadlines, and its statistics.

``run_scheduler`` ticks ``next_due += period`` on a :class:`~drivers.clock.Clock` (the real
one sleeps to ``spin`` before each deadline, then spins) and records each tick's lateness,
``clock.wait_until(next_due) - next_due``: how long after its deadline the tick started. A
tick that starts after the *next* deadline has overrun (a whole period missed); the
scheduler then catches up, deadlines stay absolute.

``realtime`` puts the calling thread in ``SCHED_FIFO`` and locks memory (``mlockall``, as
``cyclictest -m``) when the OS permits, and says what actually happened.
"""

from __future__ import annotations

import array
import ctypes
import ctypes.util
import gc
import math
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from drivers.clock import Clock

SCHED_OTHER = "SCHED_OTHER"
SCHED_FIFO = "SCHED_FIFO"
#: SCHED_FIFO priority used by the bench for both our scheduler and cyclictest.
DEFAULT_PRIORITY = 80


def percentile(values: np.ndarray, q: float) -> float:
    """The smallest sample ``v`` with at least ``q`` % of samples ``<= v`` (inverted CDF).

    The same rule reads a percentile off cyclictest's histogram, so both sides of the
    comparison use one definition: of 1000 samples, p99.9 is the 999th smallest. NaN for
    no samples.
    """
    n = len(values)
    if n == 0:
        return float("nan")
    rank = max(1, math.ceil(q / 100.0 * n - 1e-9))  # 1-based; tolerate 99.9/100*1000 > 999
    return float(np.partition(np.asarray(values, dtype=float), rank - 1)[rank - 1])


@dataclass(frozen=True)
class LatenessStats:
    """Summary of tick lateness. Times in µs; ``overruns`` counts ticks that started after
    the next tick's deadline (lateness > period)."""

    ticks: int
    p50_us: float
    p99_us: float
    p999_us: float
    max_us: float
    mean_us: float
    overruns: int

    def as_dict(self) -> dict[str, float]:
        return {"p50": self.p50_us, "p99": self.p99_us, "p999": self.p999_us, "max": self.max_us}


def lateness_stats(lateness_s: np.ndarray, period_s: float) -> LatenessStats:
    """Statistics of per-tick lateness (seconds, shape (ticks,)) for a loop of ``period_s``."""
    late = np.asarray(lateness_s, dtype=float)
    us = late * 1e6
    return LatenessStats(
        ticks=len(late),
        p50_us=percentile(us, 50),
        p99_us=percentile(us, 99),
        p999_us=percentile(us, 99.9),
        max_us=float(us.max()) if len(us) else float("nan"),
        mean_us=float(us.mean()) if len(us) else float("nan"),
        overruns=int(np.count_nonzero(late > period_s)),
    )


@dataclass(frozen=True)
class SchedulerRun:
    """One scheduler measurement. ``lateness_s`` has shape (ticks,), seconds."""

    rate_hz: float
    lateness_s: np.ndarray = field(repr=False)
    stats: LatenessStats
    wall_s: float
    cpu_s: float
    sched: str
    priority: int
    memory_locked: bool
    spin_us: float | None

    @property
    def cpu_percent(self) -> float:
        """Process CPU time over wall time during the run, % of one core."""
        return 100.0 * self.cpu_s / self.wall_s if self.wall_s > 0 else float("nan")


def run_scheduler(
    clock: Clock, rate_hz: float, ticks: int, *, warmup: int = 50
) -> tuple[np.ndarray, float, float]:
    """Tick ``ticks`` times at ``rate_hz`` on ``clock``; returns ``(lateness_s, wall_s, cpu_s)``.

    Deadlines are absolute (``next_due += period``) from the first tick after ``warmup``
    untimed ticks. The garbage collector is paused during the run (a real-time loop does
    the same); the per-tick work is one clock read and one store into a preallocated array.
    """
    if rate_hz <= 0 or ticks < 1:
        raise ValueError(f"need rate_hz > 0 and ticks >= 1, got {rate_hz}, {ticks}")
    period = 1.0 / rate_hz
    late = array.array("d", bytes(8 * ticks))
    wait_until = clock.wait_until
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        next_due = clock.now() + period
        for _ in range(warmup):
            wait_until(next_due)
            next_due += period
        c0, w0 = time.process_time(), clock.now()
        for k in range(ticks):
            late[k] = wait_until(next_due) - next_due
            next_due += period
        wall, cpu = clock.now() - w0, time.process_time() - c0
    finally:
        if gc_was_enabled:
            gc.enable()
    return np.frombuffer(late, dtype=float).copy(), wall, cpu


def measure_scheduler(
    clock: Clock,
    rate_hz: float,
    ticks: int,
    *,
    sched: str = "auto",
    priority: int = DEFAULT_PRIORITY,
) -> SchedulerRun:
    """:func:`run_scheduler` inside :func:`realtime` (``sched``: auto, fifo or other)."""
    with realtime(sched, priority) as (actual, locked):
        lateness, wall, cpu = run_scheduler(clock, rate_hz, ticks)
    spin_s = getattr(clock, "spin_s", None)
    return SchedulerRun(
        rate_hz=rate_hz,
        lateness_s=lateness,
        stats=lateness_stats(lateness, 1.0 / rate_hz),
        wall_s=wall,
        cpu_s=cpu,
        sched=actual,
        priority=priority if actual == SCHED_FIFO else 0,
        memory_locked=locked,
        spin_us=None if spin_s is None else spin_s * 1e6,
    )


# ----------------------------------------------------------------------------- OS scheduling
_MCL_CURRENT, _MCL_FUTURE = 1, 2


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name, use_errno=True) if name else None
    except OSError:
        return None


#: When this process last left SCHED_FIFO (time.monotonic), for ``realtime(rest_s=...)``.
_fifo_left_at = [-math.inf]


@contextmanager
def realtime(
    sched: str = "auto", priority: int = DEFAULT_PRIORITY, *, rest_s: float = 0.0
) -> Iterator[tuple[str, bool]]:
    """Run the body in SCHED_FIFO at ``priority`` with memory locked, when permitted.

    ``sched``: ``"fifo"`` or ``"auto"`` try SCHED_FIFO (falling back to SCHED_OTHER when the
    OS refuses); ``"other"`` leaves scheduling alone. Yields ``(class in effect, memory
    locked)``; the previous policy is restored and memory unlocked on exit.

    ``rest_s``: first sleep until this long after the process last left SCHED_FIFO. A
    SCHED_FIFO thread that busy-polls (the SDK does) for more than the kernel's RT budget
    (``sched_rt_runtime_us``, 0.95 s of every 1 s) is stopped for the rest of the second;
    resting between timed runs keeps every run inside the budget.
    """
    if sched not in ("auto", "fifo", "other"):
        raise ValueError(f"sched must be auto, fifo or other, got {sched!r}")
    has_sched = hasattr(os, "sched_setscheduler")
    if sched != "other" and has_sched and rest_s > 0:
        wait = _fifo_left_at[0] + rest_s - time.monotonic()
        if wait > 0:
            time.sleep(wait)
    old = (os.sched_getscheduler(0), os.sched_getparam(0)) if has_sched else None
    actual = SCHED_OTHER
    if sched != "other" and has_sched:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            actual = SCHED_FIFO if os.sched_getscheduler(0) == os.SCHED_FIFO else SCHED_OTHER
        except (PermissionError, OSError):
            actual = SCHED_OTHER
    libc = _libc() if actual == SCHED_FIFO else None
    locked = libc is not None and libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0
    try:
        yield actual, locked
    finally:
        if locked and libc is not None:  # (locked: libc is there)
            libc.munlockall()
        if old is not None and actual == SCHED_FIFO:
            os.sched_setscheduler(0, *old)
            _fifo_left_at[0] = time.monotonic()
