"""The show file's trigger strings and schedule windows: parsing, normalising, wall-clock maths.

A cue's ``trigger`` is one string or a list of them::

    "osc:/hilsim/cue/scare"   an OSC message to this address (any address; QLab's own too)
    "midi:note:60"            a MIDI note-on, note 60, channel 1 (same as "midi:note:60:ch1")
    "midi:note:60:ch2"        ... on channel 2 (channels 1-16)
    "midi:cc:64"              a control change 64 crossing to >= 64 (a foot switch), channel 1
    "key:s"                   a key typed in the terminal (or the keyboard input's name for it)
    "every:30"                every 30 s of show time (at 30, 60, 90 ... s; not at 0)
    "at:12.5"                 once, when show time reaches 12.5 s
    "daily:19:30"             every day when the local wall-clock time reaches 19:30

The first four are *input* triggers: the director turns arriving input into the same key and
hands it to :meth:`hilsim.live.show.ShowRuntime.trigger`. The last three are *timers*: the
runtime fires them itself from show time (and, for ``daily``, the wall-clock time the show
started at plus show time). :func:`normalise_key` makes ``"midi:note:60"`` and
``"midi:note:60:ch1"`` one key.

A cue's ``window = "18:00-23:00"`` lets it fire only between those local times of day; a window
whose end is before its start wraps midnight (``"22:00-02:00"``); ``"24:00"`` may end one.
Times of day are naive local time (no time-zone or daylight-saving shifts within a show).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta

#: the kinds a director feeds in (``trigger(key, t)``) and those the runtime fires from time
INPUT_KINDS = ("osc", "midi", "key")
TIMER_KINDS = ("every", "at", "daily")

_OSC_RE = re.compile(r"/[!-~]{0,254}")  # printable ASCII, no space
_OSC_BAD = set("#*,?[]{}")  # pattern characters: an address a trigger matches is literal
_MIDI_RE = re.compile(r"midi:(note|cc):(\d{1,3})(?::ch(\d{1,2}))?")
_KEY_RE = re.compile(r"key:[!-~]{1,32}")
_HHMM_RE = re.compile(r"(\d{1,2}):(\d{2})")


@dataclass(frozen=True)
class Trigger:
    """One parsed trigger string.

    ``kind``: one of :data:`INPUT_KINDS` or :data:`TIMER_KINDS`; ``key``: the normalised
    string (what the director sends for input kinds); ``value``: the timer's number (``every``:
    period s, ``at``: show time s, ``daily``: seconds after local midnight), else 0.
    """

    kind: str
    key: str
    value: float = 0.0


def _number(text: str) -> float | None:
    if not re.fullmatch(r"[0-9]+(\.[0-9]*)?|\.[0-9]+", text):
        return None
    x = float(text)
    return x if math.isfinite(x) else None


def parse_hhmm(text: str, *, allow_24: bool = False) -> float | None:
    """Seconds after midnight for ``"HH:MM"`` (00:00-23:59; ``"24:00"`` if ``allow_24``),
    else None."""
    m = _HHMM_RE.fullmatch(text)
    if m is None:
        return None
    h, mi = int(m.group(1)), int(m.group(2))
    if mi > 59 or h > 24 or (h == 24 and (mi or not allow_24)):
        return None
    return h * 3600.0 + mi * 60.0


def parse_trigger(text: object) -> Trigger:
    """The :class:`Trigger` for one trigger string; ValueError says what is wrong (one line,
    without the file and key: the caller adds them)."""
    if not isinstance(text, str):
        raise ValueError(f"a trigger is a string such as 'osc:/hilsim/cue/scare', got {text!r}")
    kind, _, rest = text.partition(":")
    if kind == "osc":
        if not _OSC_RE.fullmatch(rest) or _OSC_BAD & set(rest):
            raise ValueError(
                f"{text!r}: an OSC trigger is 'osc:/address' (printable, no spaces or "
                "pattern characters # * , ? [ ] { })"
            )
        return Trigger("osc", text)
    if kind == "midi":
        m = _MIDI_RE.fullmatch(text)
        if m is None:
            raise ValueError(f"{text!r}: a MIDI trigger is 'midi:note:<0-127>[:ch<1-16>]' or "
                             "'midi:cc:<0-127>[:ch<1-16>]'")  # fmt: skip
        number, channel = int(m.group(2)), int(m.group(3) or 1)
        if number > 127:
            raise ValueError(f"{text!r}: the note or controller number is 0-127")
        if not 1 <= channel <= 16:
            raise ValueError(f"{text!r}: the channel is ch1-ch16")
        return Trigger("midi", f"midi:{m.group(1)}:{number}:ch{channel}")
    if kind == "key":
        if not _KEY_RE.fullmatch(text):
            raise ValueError(f"{text!r}: a key trigger is 'key:<name>' (1-32 printable characters)")
        return Trigger("key", text)
    if kind == "every":
        x = _number(rest)
        if x is None or not x > 0 or x > 1e9:
            raise ValueError(f"{text!r}: 'every:<seconds>' needs a number > 0, e.g. 'every:30'")
        return Trigger("every", f"every:{x:g}", x)
    if kind == "at":
        x = _number(rest)
        if x is None or x > 1e12:
            raise ValueError(f"{text!r}: 'at:<seconds>' needs a show time >= 0, e.g. 'at:12.5'")
        return Trigger("at", f"at:{x:g}", x)
    if kind == "daily":
        x = parse_hhmm(rest)
        if x is None:
            raise ValueError(f"{text!r}: 'daily:HH:MM' needs a time of day 00:00-23:59")
        return Trigger("daily", f"daily:{rest}", x)
    raise ValueError(
        f"{text!r}: unknown trigger; use osc:/address, midi:note:N[:chC], midi:cc:N[:chC], "
        "key:K, every:S, at:S or daily:HH:MM"
    )


def normalise_key(key: str) -> str:
    """A trigger key as the cues store it: ``"midi:note:60"`` -> ``"midi:note:60:ch1"``; other
    strings (and unparsable ones) unchanged. Never raises."""
    if key.startswith("midi:"):
        try:
            return parse_trigger(key).key
        except ValueError:
            return key
    return key


@dataclass(frozen=True)
class Window:
    """Local times of day a cue may fire in: ``start_s`` <= time < ``end_s`` (seconds after
    midnight); wraps midnight when ``end_s`` < ``start_s``."""

    start_s: float
    end_s: float
    text: str

    def contains(self, day_s: float) -> bool:
        """Whether ``day_s`` (seconds after local midnight, 0 <= day_s < 86400) is inside."""
        if self.start_s < self.end_s:
            return self.start_s <= day_s < self.end_s
        return day_s >= self.start_s or day_s < self.end_s


def parse_window(text: object) -> Window:
    """The :class:`Window` for ``"HH:MM-HH:MM"``; ValueError (one line) otherwise."""
    if isinstance(text, str):
        a, sep, b = text.partition("-")
        start, end = parse_hhmm(a.strip()), parse_hhmm(b.strip(), allow_24=True)
        if sep and start is not None and end is not None:
            if start == end:
                raise ValueError(f"{text!r}: the window is empty (start = end); leave it out "
                                 "to allow any time")  # fmt: skip
            return Window(start, end, text)
    raise ValueError(f"a window is 'HH:MM-HH:MM' in local time, e.g. '18:00-23:00', got {text!r}")


def day_seconds(wall: datetime) -> float:
    """Seconds after the wall-clock time's midnight."""
    return wall.hour * 3600.0 + wall.minute * 60.0 + wall.second + wall.microsecond * 1e-6


def next_daily(wall: datetime, at_s: float) -> datetime:
    """The first wall-clock time at or after ``wall`` whose time of day is ``at_s`` s."""
    midnight = wall.replace(hour=0, minute=0, second=0, microsecond=0)
    nxt = midnight + timedelta(seconds=at_s)
    return nxt if nxt >= wall else nxt + timedelta(days=1)


class Timers:
    """The timer triggers (``every``, ``at``, ``daily``) of a show, due by show time.

    ``wall_start``: the local wall-clock time at show time 0 (needed only for ``daily``).
    """

    def __init__(self, triggers: Sequence[Trigger], wall_start: datetime | None) -> None:
        self.triggers = tuple(tr for tr in triggers if tr.kind in TIMER_KINDS)
        if wall_start is None and any(tr.kind == "daily" for tr in self.triggers):
            raise ValueError("a daily trigger needs the wall-clock time the show started at")
        self.wall_start = wall_start
        self._next: dict[int, datetime] = {}

    def due(self, prev: float, t: float) -> list[str]:
        """The keys of the timers due in (prev, t] (show time, s; ``prev`` -inf at the first
        tick), each once: ``at:T`` when T is passed (again after time went back), ``every:N``
        when a multiple of N > 0 is passed (once, however many), ``daily:HH:MM`` when the
        wall clock (``wall_start`` + t) reaches that time of day (once a day; at a first tick
        past it, tomorrow)."""
        keys: list[str] = []
        for i, trig in enumerate(self.triggers):
            if trig.kind == "at":
                due = prev < trig.value <= t
            elif trig.kind == "every":
                n = trig.value
                due = t >= n and math.floor(t / n) > math.floor(max(prev, 0.0) / n)
            else:
                assert self.wall_start is not None  # __init__ refused a daily without it
                wall = self.wall_start + timedelta(seconds=t)
                nxt = self._next.get(i)
                if nxt is None:
                    nxt = self._next[i] = next_daily(wall, trig.value)
                due = wall >= nxt
                while nxt <= wall:
                    nxt += timedelta(days=1)
                self._next[i] = nxt
            if due and trig.key not in keys:
                keys.append(trig.key)
        return keys
