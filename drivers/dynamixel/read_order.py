"""The order a Sync Read asks its servos in, and which replies may be a late one.

* After a failed read, the first servo missing goes to the back of the order: a silent servo
  silences those after it in a chain, so a dead one costs the others a tick or two.
* A late Fast Sync Read block is never a later read's reading: a servo missing at a later
  place is *headerless-suspect* and a servo missing first *headed-suspect* for
  :data:`LATE_BLOCK_S` (at most :data:`MAX_SUSPECT_S`), and their blocks are not taken
  where a late one could stand.
* A late plain status packet is told by its length: after a plain read, the servos it did
  not read are busy at that length for :data:`PLAIN_LATE_S`, and the next reads ask another
  of :data:`PLAIN_LENGTHS`.

The reasoning, the costs and what is left: ``docs/read_order.md``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, MutableSequence, Sequence

from drivers.dynamixel.fast_reply import STALE
from drivers.protocol2 import control_table as ct

#: how long a servo missing from a Fast reply stays suspect (s), from when the adapter could
#: have shown the bytes the read gave up on: a read that begins before then does not keep
#: what may be its late reply (a read lasts up to its timeout, so late replies up to a few ms
#: more are kept out too: row 8's, up to 9.5 ms, are). Short, so a servo back from a
#: brownout is read again soon
LATE_BLOCK_S = 0.005
#: ... and renewed, while its readings taken back may themselves have been late replies, up
#: to this long after it last went missing (so that two suspects taking turns end)
MAX_SUSPECT_S = 2 * LATE_BLOCK_S
#: how long a plain read that failed keeps its length busy (s), from when the adapter could
#: have shown what it gave up on. Longer than LATE_BLOCK_S: late replies add up along a plain
#: chain (each servo answers after the one before, so every late one delays those after
#: it: row 8's three servos, each up to 9.5 ms late, bring a packet ~30 ms after its read),
#: and the window costs only a few bytes a servo in the reads after a failed one
PLAIN_LATE_S = 0.040
#: the lengths a plain Sync Read of Present Position asks, in the order tried: the position
#: and 0-11 bytes after it (Velocity Trajectory .. Present Temperature, the same addresses on
#: every X series), but not the length of a block the bus reads from one servo in a show (a
#: late reply to a health read, 7 bytes, would pass for that servo's). Eleven
PLAIN_LENGTHS = tuple(
    n
    for n in range(
        ct.PRESENT_POSITION.size, ct.PRESENT_TEMPERATURE.end - ct.PRESENT_POSITION.addr + 1
    )
    if n not in {b.size for b in (ct.HEALTH_BLOCK, ct.HEALTH_WATCHDOG_BLOCK, ct.CONDITION_BLOCK)}
)


class ReadOrder:
    """Indices of the servos in the order the next Sync Read asks them, with the rules above."""

    def __init__(self, n: int) -> None:
        self.order = list(range(n))
        #: servo index -> until when (bus clock, s) a late block of it may still come without
        #: a header (it went missing at a later place) / a late reply may still come that
        #: starts with its header and block (it went missing first)
        self.headerless: dict[int, float] = {}
        self.headed: dict[int, float] = {}
        #: plain read length -> {servo index: until when a late status packet of it, of
        #: that length, may still come}
        self.busy_lengths: dict[int, dict[int, float]] = {}
        self._taken_back: set[int] = set()  # readings distrust() took back in this read
        self._since: dict[int, float] = {}  # when each suspect's suspicion began

    @property
    def suspect(self) -> bool:
        return bool(self.headerless or self.headed)

    def plain_length(self, now: float) -> tuple[int, tuple[int, ...]]:
        """The length the plain read beginning ``now`` asks, and the servos whose packet of
        that length may be a late one (their readings are not kept): the first length of
        :data:`PLAIN_LENGTHS` with none, else the one with the fewest."""
        busy = self.busy_lengths
        for n, book in list(busy.items()):
            for k in [k for k, until in book.items() if until <= now]:
                del book[k]
            if not book:
                del busy[n]
        free = next((n for n in PLAIN_LENGTHS if n not in busy), None)
        if free is not None:
            return free, ()
        n = min(PLAIN_LENGTHS, key=lambda n: len(busy[n]))
        return n, tuple(busy[n])

    def late_ids(self, ids: Sequence[int]) -> frozenset[int]:
        """The IDs (``ids`` by servo index) that may still send a late packet, of any length."""
        return frozenset(ids[k] for book in self.busy_lengths.values() for k in book)

    def take_back(
        self,
        servos: Iterable[int],
        pos: MutableSequence[float],
        status: MutableSequence[int],
        errors: MutableSequence[int],
    ) -> list[int]:
        """Take back the readings of ``servos``; returns the statuses as they came."""
        came = list(status)
        for k in servos:
            pos[k], status[k], errors[k] = math.nan, STALE, 0
        return came

    def plain_unread(self, length: int, servos: Iterable[int], now: float) -> None:
        """After a read of ``length`` bytes that did not read ``servos`` (indices): each may
        still send its packet, late, until ``now`` + :data:`PLAIN_LATE_S` (``now``: when the
        adapter could have shown what the read gave up on)."""
        if length not in PLAIN_LENGTHS:
            return  # (a late packet of another length is never a plain read's)
        book = self.busy_lengths.setdefault(length, {})
        until = now + PLAIN_LATE_S
        for k in servos:
            book[k] = max(book.get(k, until), until)

    def distrust(
        self,
        now: float,
        pos: MutableSequence[float],
        status: MutableSequence[int],
        errors: MutableSequence[int],
    ) -> None:
        """Take back what a Fast reply may have taken from a late one: all of it if its first
        servo's late reply may still come (header and all), else from the first servo past
        the first place whose late block may still come (and the blocks after it). ``now``
        is when the read began: any byte of it may have come from then on."""
        for book in (self.headerless, self.headed):
            for k in [k for k, until in book.items() if until <= now]:
                del book[k]
        for k in [k for k in self._since if k not in self.headed and k not in self.headerless]:
            del self._since[k]
        order = self.order
        start = 0 if order[0] in self.headed else None
        if start is None:
            start = next((p for p in range(1, len(order)) if order[p] in self.headerless), None)
            if start is None:
                return
        for j in order[start:]:
            if status[j] != STALE:
                self._taken_back.add(j)
            pos[j], status[j], errors[j] = math.nan, STALE, 0

    def after(self, status: MutableSequence[int], now: float, fast: bool) -> int | None:
        """The order for the next read after a (``fast``) read with these statuses; returns
        the position from which its replies may still come: the first servo really missing,
        else the first reading taken back (None if no servo is STALE)."""
        order, taken_back, self._taken_back = self.order, self._taken_back, set()
        i: int | None  # the place returned
        stale = [p for p, k in enumerate(order) if status[k] == STALE]
        if not stale:
            return None
        if not fast:
            i, k = stale[0], order[stale[0]]
            if i + 1 < len(order):  # the chain broke here: ask it last next time
                self.order = [*order[:i], *order[i + 1 :], k]
            return i
        until = now + LATE_BLOCK_S
        for p in stale:  # a suspect's reading taken back may have been a late one, its own
            j = order[p]  # reply late in turn: suspect on, but not past MAX_SUSPECT_S in all
            if j in taken_back and j in self._since:
                cap = self._since[j] + MAX_SUSPECT_S
                if cap > now:
                    book = self.headerless if p else self.headed
                    book[j] = max(book.get(j, 0.0), min(until, cap))
        i = next((p for p in stale if order[p] not in taken_back), None)  # really missing
        if i is None:
            self.order = self._arranged(list(order))
            return stale[0]
        k, rest = order[i], order[:i] + order[i + 1 :]
        self._since[k] = now  # (renewals are capped from its last real miss)
        (self.headerless if i else self.headed)[k] = until  # its reply may come late
        self.order = self._arranged([k, *rest] if i else [*rest, k])
        return i

    def _arranged(self, want: list[int]) -> list[int]:
        """``want`` with a first servo no late reply of which can start a later one (one
        whose late blocks come without a header if there is one: only there is it read),
        then the others, then those whose headerless blocks may still come."""
        headed, headerless = self.headed, self.headerless
        first = next((j for j in want if j in headerless and j not in headed), None)
        if first is None:
            first = next((j for j in want if j not in headed), want[0])
        others = [j for j in want if j != first]
        return [
            first,
            *(j for j in others if j not in headerless),
            *(j for j in others if j in headerless),
        ]
