"""Injected time: one interface, a real monotonic clock and a virtual clock that jumps.

Everything that needs "now" or has to wait takes a :class:`Clock`. Times are seconds
(float) from an arbitrary origin. The virtual clock never sleeps: waiting moves it
forward, so a ten-minute show runs in seconds and tests never sleep in real time.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

#: the default spin window of :class:`MonotonicClock` (s): sleep until this close to a
#: deadline, then spin. The rig key ``loop.spin_us`` overrides it.
DEFAULT_SPIN_S = 200e-6


@runtime_checkable
class Clock(Protocol):
    #: True when waiting moves time instead of letting it pass (nothing ever sleeps).
    virtual: bool

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

    ``wait_until`` sleeps to ``spin_s`` before the deadline (the OS wakes threads late
    by ~0.1-1 ms), then spins on the clock for the last stretch: the *spin window*. A rig sets
    it with ``loop.spin_us``. ``now`` and ``sleep`` are the time source (default
    ``time.perf_counter`` and ``time.sleep``); tests pass a simulated one.
    """

    virtual = False

    def __init__(
        self,
        spin_s: float = DEFAULT_SPIN_S,
        *,
        now: Callable[[], float] | None = None,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        if not (spin_s >= 0.0 and math.isfinite(spin_s)):
            raise ValueError(f"spin_s must be finite and >= 0, got {spin_s!r}")
        self.spin_s = float(spin_s)
        self._now = time.perf_counter if now is None else now
        self._sleep = time.sleep if sleep is None else sleep

    def now(self) -> float:
        return self._now()

    def wait_until(self, t: float, idle: threading.Event | None = None) -> float:
        now = self._now()
        remaining = t - now - self.spin_s
        if remaining > 0.0:
            if idle is None:
                self._sleep(remaining)
            else:  # other threads may work while we sleep, not while we spin or run
                if isinstance(idle, Slack):
                    idle.until = t - self.spin_s
                idle.set()
                self._sleep(remaining)
                idle.clear()
        while (now := self._now()) < t:
            pass
        return now


class VirtualClock:
    """A clock that only moves when told to: ``wait_until`` and ``advance`` jump."""

    virtual = True

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
