"""The live layer: which live input holds each joint, and handing joints back to the show.

One joint, one target, in this order (``docs/live.md``, "Who drives a joint")::

    live        a value from a live input (OSC, MIDI, gamepad, Bottango, Show.set_joint,
                teach) holds the joint until it is released
    cue         else the clip of the cue playing, if it drives the joint
    timeline    else the timeline's clip
    idle        else the idle layer's clip
    rig         else the rig's own ``target``

:class:`LiveLayer` is the one place that takes and releases joints: every input, and every
control (OSC ``/hilsim/release``, ``Show.release``, a panel), goes through
:meth:`LiveLayer.take` and :meth:`LiveLayer.release`. A release clears the joint's live target,
so the joint follows the layer below from the next tick; its spring and the safety filter
carry it there (a step in the target, never in the command). ``release_after_s`` per input: a
value not refreshed for that long is released (:meth:`LiveLayer.expire`); ``None`` holds it
for good, as a lost input always did.

Each take and release is one event (``live_take``, ``live_release``, ``release_ignored``). No
clock reads, no locks: the director calls it once per tick from the loop's thread.

A new input joins in ``hilsim.live.inputs`` (built, opened, polled there), which hands each
value to ``Director.set_value(joint, deg, t, source, events, standing=...)`` and each release
to ``Director.release(joint, t, reason, source)``; its ``release_after_s`` is read by
``hilsim.live.director.release_after``. A program or a panel calls ``Show.release``
(:class:`~hilsim.live.controls.Controls`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

from hilsim.live.inbox import LiveEvent

__all__ = ["TEACH", "LiveLayer", "LiveTarget"]

#: the holder name of a joint moved by hand (teach): never released, never expires
TEACH = "teach"


class LiveTarget(Protocol):
    """A joint's track with a live slot (the director's ``DirectedTrack``)."""

    live: float | None


class LiveLayer:
    """Who holds each joint (module docstring).

    Args:
        names: the joints, in the tracks' order.
        tracks: each joint's track; ``live`` (rad) set means a live input holds it.
        release_after_s: per input (``"osc"``, ``"midi"`` ...): seconds without a fresh value
            after which its joints are released; missing or None: held for good.
        below: joint index -> what drives it without a live value (``"idle breathe"``).
    """

    def __init__(
        self,
        names: Sequence[str],
        tracks: Sequence[LiveTarget],
        release_after_s: Mapping[str, float | None],
        below: Callable[[int], str],
    ) -> None:
        self.names, self.tracks = tuple(names), tracks
        self.release_after_s = {k: v for k, v in release_after_s.items() if v is not None}
        for source, s in self.release_after_s.items():
            if not (math.isfinite(s) and s > 0):
                raise ValueError(f"{source}: release_after_s = {s!r}: seconds, > 0")
        self.below = below
        n = len(self.names)
        #: the input holding each joint (None: the show's layers drive it)
        self.holder: list[str | None] = [None] * n
        #: the show time of each held joint's last fresh value
        self.last_t = [0.0] * n
        #: the holder's input is lost and the joint holds its last value
        self.lost = [False] * n
        #: a standing value released: not taken again until it changes (gamepad, Bottango)
        self._released_at: dict[tuple[int, str], float] = {}
        self._next_expiry = math.inf
        self._ignored_said: dict[str | None, float] = {}  # joint -> when last said
        self.counts = {"joints_taken": 0, "joints_released": 0, "releases_ignored": 0}

    # ------------------------------------------------------------------ taking
    def take(
        self, i: int, rad: float, source: str, t: float, *, standing: bool = False
    ) -> LiveEvent | None:
        """A fresh value ``rad`` for joint ``i`` from ``source`` at show time ``t``. Returns a
        ``live_take`` event when the joint changes hands. ``standing``: an input that reports
        its value every tick, fresh or not (gamepad, Bottango): after a release it takes the
        joint again only once the value changes."""
        holder = self.holder[i]
        if standing:
            was = self._released_at.get((i, source))
            if was is not None:
                if was == rad:
                    return None
                del self._released_at[(i, source)]
            if holder == source and self.tracks[i].live == rad:
                return None  # the same value again: not fresh
        self.tracks[i].live = rad
        self.last_t[i] = t
        self.lost[i] = False
        after = self.release_after_s.get(source)
        if after is not None:
            self._next_expiry = min(self._next_expiry, t + after)
        if holder == source:
            return None
        self.holder[i] = source
        self.counts["joints_taken"] += 1
        name = self.names[i]
        was_below = self.below(i) if holder is None else f"live {holder}"
        return LiveEvent(t, "live_take", source, {
            "joint": name, "deg": math.degrees(rad), "from": was_below,
            "message": f"{name}: taken by {source} at {math.degrees(rad):.3f} deg "
                       f"(was {was_below})",
        })  # fmt: skip

    def teach(self, i: int, rad: float) -> None:
        """Joint ``i`` is moved by hand (teach): held by :data:`TEACH` for the whole show."""
        self.holder[i] = TEACH
        self.tracks[i].live = rad

    # ------------------------------------------------------------------ releasing
    def release(
        self, joint: str | None, t: float, reason: str, *, source: str = "show"
    ) -> list[LiveEvent]:
        """Hand ``joint`` (None: every joint) back to the layers below at show time ``t``;
        ``reason`` says who asked. Raises KeyError for a joint the rig does not have. A joint
        moved by hand (teach) is not released. Nothing held: a ``release_ignored`` event, at
        most one a second per joint (a button pressed again and again says it once)."""
        if joint is None:
            which = range(len(self.names))
        else:
            if joint not in self.names:
                raise KeyError(f"no joint {joint!r} (joints: {', '.join(self.names)})")
            which = range(self.names.index(joint), self.names.index(joint) + 1)
        out = [self._free(i, t, reason) for i in which if self.holder[i] not in (None, TEACH)]
        if not out:
            self.counts["releases_ignored"] += 1
            said = self._ignored_said.get(joint)
            if said is not None and 0.0 <= t - said < 1.0:
                return out
            self._ignored_said[joint] = t
            what = "no joint is" if joint is None else f"{joint} is not"
            out.append(LiveEvent(t, "release_ignored", source, {
                "joint": joint, "reason": reason,
                "message": f"{reason}: {what} held by a live input",
            }))  # fmt: skip
        return out

    def expire(self, t: float) -> list[LiveEvent]:
        """Release every joint whose holder's ``release_after_s`` has passed since its last
        fresh value (``t > last + release_after_s``). Bounded: a skip on most ticks."""
        if not t > self._next_expiry:
            return []
        out: list[LiveEvent] = []
        nxt = math.inf
        for i, holder in enumerate(self.holder):
            after = None if holder is None else self.release_after_s.get(holder)
            if after is None:
                continue
            due = self.last_t[i] + after
            if t > due:
                silent = t - self.last_t[i]
                out.append(self._free(i, t, f"no {holder} value for {silent:.3f} s "
                                            f"(release_after_s {after:g})"))  # fmt: skip
            else:
                nxt = min(nxt, due)
        self._next_expiry = nxt
        return out

    def _free(self, i: int, t: float, reason: str) -> LiveEvent:
        holder = self.holder[i]
        assert holder is not None
        rad = self.tracks[i].live
        if rad is not None:
            self._released_at[(i, holder)] = rad
        self.tracks[i].live = None
        self.holder[i] = None
        self.lost[i] = False
        self.counts["joints_released"] += 1
        name, to = self.names[i], self.below(i)
        return LiveEvent(t, "live_release", holder, {
            "joint": name, "reason": reason, "to": to,
            "message": f"{name}: released by {reason}; back to {to} through its spring",
        })  # fmt: skip

    # ------------------------------------------------------------------ lost input
    def mark_lost(self, source: str, joints: Sequence[str] | None, lost: bool) -> None:
        """``source``'s input is lost (or back): the joints it holds among ``joints`` (None:
        all it holds) are marked. A joint it no longer holds is not."""
        for i, holder in enumerate(self.holder):
            if holder == source and (joints is None or self.names[i] in joints):
                self.lost[i] = lost

    def held_by(self, source: str) -> list[str]:
        return [n for n, h in zip(self.names, self.holder, strict=True) if h == source]

    # ------------------------------------------------------------------ the status line
    def label(self, i: int) -> str:
        """What drives joint ``i``: ``"live osc"``, ``"LOST osc"``, ``"teach"``, or the layer
        below (``"cue scare"``, ``"idle breathe"``, ``"rig"``)."""
        holder = self.holder[i]
        if holder is None:
            return self.below(i)
        if holder == TEACH:
            return TEACH
        return f"{'LOST' if self.lost[i] else 'live'} {holder}"
