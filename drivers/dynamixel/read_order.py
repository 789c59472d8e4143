"""The order a Sync Read asks its servos in, and which blocks of a Fast reply may be late.

In a Sync Read chain a silent servo silences those after it (each waits for the one before),
so after a failed read the first servo missing goes to the back of the order: a dead one
costs the others a tick or two, not every tick.

A reply later than the wait after a failed read still comes. A Fast Sync Read reply is one
packet: the first servo sends the header and its block, each other servo only its block
(``ERR ID data CRC``), its CRC running on over what it heard. So a late reply is one of two
things, and either can be taken for a later read's when that read misses its own reply:

* a servo S missing at a later place sends its block (and the blocks after it follow)
  without a header: it can fill S's place in a later reply, the ID right and the running
  CRC passing 1 time in 256 (it keeps only 8 bits across each block's CRC: its two bytes
  fold the state to their XOR). Until :data:`LATE_BLOCK_S` after the adapter could have
  shown what the read gave up on, S is *headerless-suspect*: asked first, where its block
  comes with the header; anywhere else its block, and those after it, are not readings
  (headerless suspects are asked last, so they cost only themselves);
* a servo S missing first sends the header and its block, whole, and the rest of the
  chain after it: a later read that starts with S takes it whole, as far as its order
  agrees. S is *headed-suspect* as long: not asked first (anywhere else its late reply's
  header cannot pass for a block), and a read that still starts with it (every servo is
  headed-suspect, or there is only one) is not a reading at all.

A suspect's reading taken back may itself have been a late reply, its own reply late in
turn: its suspicion is renewed, but not past :data:`MAX_SUSPECT_S` after it last went
missing, so that suspicion ends (two suspects would otherwise keep each other suspect).
The cost: a servo that fails now and then makes the others miss some reads too (asked
first, it takes the chain down when it fails there), a dead one until its budget ends the
show; a servo alone on its bus is not read for a read or two after each miss.
What is left: a reply later than that (``tests/hilsim/test_fault_matrix.py`` row 8: 15 % of
replies up to 9.5 ms late at 250 Hz, never a reading from another read); a servo after the
first one missing whose own reply is late on top (its block comes alone, without a header,
and it is not suspect); and Plain Sync Read, whose late status packets are whole packets
with their own CRC, the missing servo's and those after it: the wait and the changed order
do not keep them out (row 8's late replies, read plain, gave earlier values in all 12 runs).
"""

from __future__ import annotations

import math
from collections.abc import MutableSequence

from drivers.dynamixel.fast_reply import STALE

#: how long a servo missing from a Fast reply stays suspect (s), from when the adapter could
#: have shown the bytes the read gave up on: a read that begins before then does not keep
#: what may be its late reply (a read lasts up to its timeout, so late replies up to a few ms
#: more are kept out too: row 8's, up to 9.5 ms, are). Short, so a servo back from a
#: brownout is read again soon
LATE_BLOCK_S = 0.005
#: ... and renewed, while its readings taken back may themselves have been late replies, up
#: to this long after it last went missing (so that two suspects taking turns end)
MAX_SUSPECT_S = 2 * LATE_BLOCK_S


class ReadOrder:
    """Indices of the servos in the order the next Sync Read asks them, with the rules above."""

    def __init__(self, n: int) -> None:
        self.order = list(range(n))
        #: servo index -> until when (bus clock, s) a late block of it may still come without
        #: a header (it went missing at a later place) / a late reply may still come that
        #: starts with its header and block (it went missing first)
        self.headerless: dict[int, float] = {}
        self.headed: dict[int, float] = {}
        self._taken_back: set[int] = set()  # readings distrust() took back in this read
        self._since: dict[int, float] = {}  # when each suspect's suspicion began

    @property
    def suspect(self) -> bool:
        return bool(self.headerless or self.headed)

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
