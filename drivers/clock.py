"""Injected time: one interface, a real monotonic clock and a virtual clock that jumps.

Everything that needs "now" or has to wait takes a :class:`Clock`. Times are seconds
(float) from an arbitrary origin. The virtual clock never sleeps: waiting moves it
forward, so a ten-minute show runs in seconds and tests never sleep in real time.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol, runtime_checkable

#: the default spin window of :class:`MonotonicClock` (s): sleep until this close to a
#: deadline, then spin. The rig key ``loop.spin_us`` overrides it. With precise timers
#: (:func:`precise_timers`) Linux wakes a sleeper well within 100 µs, so the loop still
#: reaches its deadline spinning, at less CPU than a wider window. ``python -m
#: hilsim.bench.cpu`` compares windows; the figures are in docs/performance.md.
DEFAULT_SPIN_S = 100e-6
#: how fast the learned spin window (``MonotonicClock.window_s``) comes down (s a sleep): it
#: is the latest wake-up of the recent past, held, less this for each sleep since that woke
#: sooner; a wake-up later than it raises it at once. So the window is the worst lateness of
#: the last few seconds (40 µs of it lost in 800 sleeps, 3.2 s at 250 Hz), and a tick starts
#: late only where a wake-up is later than any in that time: the lateness p99 of a fixed
#: window on a calm host, and a fixed window itself on one whose wake-ups pass ``spin_s``.
#: (Tracking a percentile instead, the 99th or 99.5th, lagged a bursty host: under
#: SCHED_FIFO at load 6-10 its lateness p99 was 11-86 µs where a fixed window had 0.2-2.4.)
WAKE_DECAY_S = 0.05e-6


#: Linux ``prctl`` options for the calling thread's timer slack (ns): the kernel may fire a
#: sleeping thread's timer up to this much late, to batch wake-ups (default 50 µs).
PR_SET_TIMERSLACK = 29
PR_GET_TIMERSLACK = 30
#: The timer slack a real-time loop asks for (ns): timers fire when due.
PRECISE_SLACK_NS = 1


class _Prctl(Protocol):
    """``prctl(option, arg2, arg3, arg4, arg5)`` through ctypes: returns the C ``int``."""

    def __call__(
        self, option: int, arg2: int | ctypes.c_ulong, arg3: int, arg4: int, arg5: int, /
    ) -> int: ...


_libc_cache: list[_Prctl | None] = []


def _libc() -> _Prctl | None:
    """The C library's ``prctl`` (the process's own symbols: no library search), or None."""
    if not _libc_cache:
        lib: _Prctl | None = None
        if sys.platform.startswith("linux"):
            try:
                lib = ctypes.CDLL(None, use_errno=True).prctl
            except (OSError, AttributeError):
                lib = None
        _libc_cache.append(lib)
    return _libc_cache[0]


def timer_slack_ns() -> int | None:
    """The calling thread's timer slack (ns), or None where it cannot be read (not Linux)."""
    prctl = _libc()
    if prctl is None:
        return None
    value = prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0)
    return None if value < 0 else int(value)


def set_timer_slack_ns(ns: int) -> bool:
    """Set the calling thread's timer slack (ns; 0 restores the thread's default). False
    where it cannot be set."""
    prctl = _libc()
    if prctl is None:
        return False
    return prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(int(ns)), 0, 0, 0) == 0


@contextlib.contextmanager
def precise_timers(ns: int = PRECISE_SLACK_NS) -> Iterator[bool]:
    """The calling thread's timer slack at ``ns`` for the ``with`` block, then as it was.

    A sleep to a deadline (``time.sleep``, ``select``'s timeout) then wakes within the OS's
    wake-up latency of it instead of up to 50 µs later, so a loop can sleep closer to its
    deadline and spin less (:class:`MonotonicClock`'s spin window). Yields whether it was
    set (False: not Linux, or refused; nothing changed). Per thread: set it in the thread
    that sleeps."""
    old = timer_slack_ns()
    ok = old is not None and set_timer_slack_ns(ns)
    try:
        yield ok
    finally:
        if ok and old is not None:  # ok implies the second; the checker cannot tell
            set_timer_slack_ns(old)


@runtime_checkable
class Clock(Protocol):
    #: True when waiting moves time instead of letting it pass (nothing ever sleeps).
    virtual: bool
    #: free time offered by every wait that names none (see :class:`MonotonicClock`); a
    #: virtual clock never sleeps, so it has none to offer and ignores it
    idle: threading.Event | None

    def now(self) -> float:
        """Current time in seconds."""

    def wait_until(self, t: float, idle: threading.Event | None = None) -> float:
        """Return once ``now() >= t``; returns ``now()``. Never returns early.

        ``idle``, if given, is set while the caller is asleep (free time other threads may
        use) and cleared before this returns.
        """


class Slack(threading.Event):
    """Free time a real-time loop offers other threads: set while the loop sleeps.

    ``until`` is when that free time ends (the loop's clock, ``time.perf_counter`` for
    :class:`MonotonicClock`). A worker thread checks it before each piece of work, so it
    stops in time without the loop having to get the interpreter back first.
    """

    def __init__(self) -> None:
        super().__init__()
        self.until = float("inf")

    def remaining(self) -> float:
        """Seconds of the current free time left (negative once it is over)."""
        return self.until - time.perf_counter()


class MonotonicClock:
    """The host's monotonic clock.

    ``wait_until`` sleeps to a *spin window* before the deadline (the OS wakes threads late:
    10-50 µs with :func:`precise_timers`, up to 50 µs more without, ~0.1-1 ms on a busy
    host), then spins on the clock for the last stretch. ``spin_s`` (a rig's
    ``loop.spin_us``) is the most it spins; with ``learn`` (the default) the window is the
    latest this host's sleeps have woken in the last few seconds (:data:`WAKE_DECAY_S`,
    :attr:`window_s`), when that is less: a host that wakes its threads at most 20 µs late
    spins ~20 µs, not ``spin_s``, and one that wakes later than ``spin_s`` spins ``spin_s``
    as a fixed window would. The sleep is one ``time.sleep``, which Linux runs as an
    absolute ``clock_nanosleep`` on the monotonic clock. ``now`` and ``sleep`` are the time
    source (default ``time.perf_counter`` and ``time.sleep``); tests pass a simulated one.
    """

    virtual = False

    def __init__(
        self,
        spin_s: float = DEFAULT_SPIN_S,
        *,
        now: Callable[[], float] | None = None,
        sleep: Callable[[float], None] | None = None,
        learn: bool = True,
    ) -> None:
        if not (spin_s >= 0.0 and math.isfinite(spin_s)):
            raise ValueError(f"spin_s must be finite and >= 0, got {spin_s!r}")
        self.spin_s = float(spin_s)
        #: the spin window in force (s): ``spin_s``, or less where this host's sleeps have
        #: woken sooner (``learn``); starts at ``spin_s``
        self.window_s = self.spin_s
        self.learn = bool(learn)
        # the recent worst wake-up (s), held up to twice spin_s: held only to spin_s, a host
        # waking later than that would see the window come down between its late wake-ups;
        # twice bounds how long a calmer host waits for it to come down
        self._wake_q = self.spin_s
        self._now = time.perf_counter if now is None else now
        self._sleep = time.sleep if sleep is None else sleep
        # the time source itself, not a method around it: a tick reads the clock ~20 times
        self.now: Callable[[], float] = self._now
        #: free time offered by every wait on this clock that names none: a real-time loop
        #: sets its telemetry writer's :class:`Slack` here for the show, so the waits inside
        #: a tick (an in-process emulator's bytes on the wire) are free time too
        self.idle: threading.Event | None = None

    def wait_until(self, t: float, idle: threading.Event | None = None) -> float:
        now = self._now()
        window = self.window_s
        remaining = t - now - window
        if remaining > 0.0:
            if idle is None:
                idle = self.idle
            if idle is None:
                self._sleep(remaining)
            else:  # other threads may work while we sleep, not while we spin or run
                if isinstance(idle, Slack):
                    idle.until = t - window
                idle.set()
                self._sleep(remaining)
                idle.clear()
            if self.learn:  # the latest recent wake-up, held, coming down slowly
                q, late = self._wake_q, self._now() - (t - window)
                q = min(late, 2.0 * self.spin_s) if late > q else max(q - WAKE_DECAY_S, 0.0)
                self._wake_q = q
                self.window_s = q if q < self.spin_s else self.spin_s
        while (now := self._now()) < t:
            pass
        return now


class VirtualClock:
    """A clock that only moves when told to: ``wait_until`` and ``advance`` jump."""

    virtual = True
    #: never used: nothing sleeps on a virtual clock (here to be a :class:`Clock`)
    idle: threading.Event | None = None

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def wait_until(self, t: float, idle: threading.Event | None = None) -> float:
        if t > self._t:
            self._t = float(t)
        return self._t

    def advance(self, dt: float) -> float:
        if dt < 0.0:
            raise ValueError(f"a clock cannot go back (dt={dt!r})")
        self._t += dt
        return self._t

    def __repr__(self) -> str:
        return f"VirtualClock(t={self._t!r})"
