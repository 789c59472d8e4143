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

from hilsim.live.netguard import TokenBucket

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


#: the keys a LineGate keeps a budget for (the least recently made is forgotten past this)
MAX_GATE_KEYS = 1024


class LineGate:
    """At most ``burst`` lines per key at once, then one per ``interval_s`` of show time; the
    last one always said.

    A line past its key's budget is held back: only the latest is kept, the ones before it are
    counted, and it is said once the budget allows with how many it stands for. So a storm of
    well-formed packets (a master seeking a thousand times a second, two consoles taking a
    universe from each other) is a line a second, and the state it left is the last line; an
    Open, a Start and a Stop in one second are three lines at once. The input acts on every
    packet; only its lines are gated."""

    def __init__(self, interval_s: float = 1.0, burst: int = 4) -> None:
        self.interval_s, self.burst = interval_s, burst
        self._budget: dict[str, TokenBucket] = {}
        self._held: dict[str, tuple[LiveEvent, int]] = {}
        self.held = 0  #: lines held back, in all (each said later or folded into one)

    def _take(self, key: str, t: float) -> bool:
        bucket = self._budget.get(key)
        if bucket is None:
            if len(self._budget) >= MAX_GATE_KEYS:  # bounded: forget the oldest not held back
                old = next((k for k in self._budget if k not in self._held), None)
                self._budget.pop(old if old is not None else next(iter(self._budget)))
            bucket = self._budget[key] = TokenBucket(1.0 / self.interval_s, self.burst, t)
        return bucket.take(t)

    def offer(self, ev: LiveEvent, key: str) -> LiveEvent | None:
        """``ev`` if it may be said now, else None (held back until :meth:`due`)."""
        if key not in self._held and self._take(key, ev.t):
            return ev
        n = self._held[key][1] + 1 if key in self._held else 1
        self._held[key] = (ev, n)
        self.held += 1
        return None

    def due(self, t: float) -> list[LiveEvent]:
        """The held lines the budget allows at show time ``t``, in the order they happened,
        each the latest of its key saying how many lines it stands for."""
        out = []
        for key, (ev, n) in list(self._held.items()):
            if self._take(key, t):
                del self._held[key]
                message = str(ev.detail.get("message", ev.kind))
                if n > 1:
                    message += f" (the last of {n} such lines held back)"
                out.append(LiveEvent(ev.t, ev.kind, ev.source,
                                     {**ev.detail, "message": message, "lines": n}))  # fmt: skip
        return sorted(out, key=lambda e: e.t)
