"""The hand-over from a receiver thread to the loop, and the record of one live-input event.

:class:`Inbox` is a bounded FIFO of ``(t, message)`` pairs: ``put`` never blocks (a full inbox
drops its *oldest* entry and counts it), and ``take_due(t)`` hands the loop, without waiting, the
entries stamped at or before ``t``. Tests put messages with future stamps up front and poll tick
by tick; a receiver thread stamps each message with the loop's clock on arrival.

:class:`LiveEvent` is one line for ``events.jsonl`` (``as_dict``).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any

#: the widest a live input's range may be (deg, either end): 100 turns. Wider ranges (1e308)
#: would overflow to inf/NaN on the way to a joint: refused at load, never a fault mid-show
MAX_LIVE_DEG = 36000.0
#: default inbox capacity: 256 messages (at MIDI's 31.25 kbit/s, ~0.25 s of the densest stream)
DEFAULT_CAPACITY = 256


@dataclass(frozen=True)
class LiveEvent:
    """One live-input event: ``t`` show time (s), ``kind`` (e.g. ``"input_lost"``), the input
    it came from (``source``, e.g. ``"midi"``) and its facts (``detail``, JSON-ready)."""

    t: float
    kind: str
    source: str
    detail: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The event as one ``events.jsonl`` object: ``{"t", "event", "source", **detail}``."""
        return {"t": self.t, "event": self.kind, "source": self.source, **self.detail}


class Inbox:
    """A bounded, thread-safe FIFO of ``(t, message)``; full: the oldest is dropped and counted.

    Args:
        capacity: most entries held (≥ 1).

    ``put`` is for one producer (a receiver thread, or a test); ``take_due`` for the loop. Stamps
    must not decrease (the loop's clock is monotonic): a stamp earlier than the last one is a
    programming error and raises ``ValueError`` (in the producer, never in the loop).
    """

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"inbox capacity must be an integer >= 1, got {capacity!r}")
        self.capacity = capacity
        self._q: deque[tuple[float, Any]] = deque()
        self._lock = threading.Lock()
        self._last_t = -math.inf
        self.dropped = 0  #: entries dropped (oldest first) because the inbox was full, in all
        self._dropped_unreported = 0

    def put(self, t: float, message: Any) -> None:
        """Add ``message`` stamped ``t`` (show time, s); never blocks."""
        t = float(t)
        if not math.isfinite(t):
            raise ValueError(f"message time must be finite, got {t!r}")
        with self._lock:
            if t < self._last_t:
                raise ValueError(
                    f"message time {t!r} s is before the previous one, {self._last_t!r} s"
                )
            self._last_t = t
            if len(self._q) >= self.capacity:
                self._q.popleft()
                self.dropped += 1
                self._dropped_unreported += 1
            self._q.append((t, message))

    def take_due(self, t: float) -> list[tuple[float, Any]]:
        """Remove and return the entries stamped at or before ``t``, oldest first (at most
        ``capacity`` of them: bounded work)."""
        with self._lock:
            q = self._q
            if not q or q[0][0] > t:
                return []
            out = []
            while q and q[0][0] <= t:
                out.append(q.popleft())
            return out

    def take_drops(self) -> int:
        """Drops since the last call (for one ``inbox_overflow`` event per poll at most)."""
        with self._lock:
            n, self._dropped_unreported = self._dropped_unreported, 0
            return n

    def __len__(self) -> int:
        return len(self._q)
