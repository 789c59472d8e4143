"""MIDI Time Code chase: quarter frames (0xF1) and full-frame SysEx -> show time, polled per tick.

**Quarter frames.** Running forward, a sender sends 4 per frame, pieces 0–7: frame, seconds,
minutes and hours, low nibble then high; piece 7's bits 1–2 are the rate (0 = 24, 1 = 25,
2 = 29.97 drop-frame, 3 = 30 fps). Pieces 0 and 4 arrive where frames start, piece 0 at the
coded instant, so when piece 7 arrives the time is the code + 7/4 frames, and the next piece 0
lands on the code + 2 frames (the "+2 frames a full code takes"). The chase locks on piece 7:
its arrival is the anchor, at the code + 7/4 frames, and the show time runs on the loop's clock
from there until the next full code re-anchors it (every 2 frames). ``timecode_locked`` names
the quarter frame (``quarter_frame``: 7) and is stamped with its arrival.

**Stop, freewheel, hold.** When quarter frames stop, the show time runs on for ``freewheel_s``
after the last one (at least one frame, the normal spacing being a quarter of that), then holds;
events ``timecode_stopped`` (no quarter frame for one frame) and ``timecode_held``. The next full
code locks again (``timecode_locked``).

**Jumps.** A new code more than ``jump_s`` away from where the running show time predicted it
(a locate, a rewind, a cut) is reported as ``timecode_jump`` with ``from_s`` and ``to_s``; the
show time takes the new value at once and the loop limits the move. A full-frame message
(``F0 7F <dev> 01 01 hr mn sc fr F7``, a locate while stopped) sets the show time and holds it
(``cued``) until quarter frames run again.

Reverse quarter frames (pieces counting down, a sender rewinding) are not chased: the show time
freewheels then holds, and one ``timecode_reverse`` event says why.
Show time = timecode − ``offset_s``. No mido needed: messages are anything with mido's
``type``, ``frame_type``, ``frame_value`` and ``data``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hilsim.live.inbox import DEFAULT_CAPACITY, Inbox, LiveEvent

#: MTC rate code -> (nominal frames per second, drop-frame)
RATES: dict[int, tuple[int, bool]] = {0: (24, False), 1: (25, False), 2: (30, True), 3: (30, False)}
RATE_NAMES = {0: "24", 1: "25", 2: "29.97df", 3: "30"}


@dataclass(frozen=True)
class Smpte:
    """One SMPTE time code, HH:MM:SS:FF at an MTC rate code (0–3, see :data:`RATES`)."""

    hours: int
    minutes: int
    seconds: int
    frames: int
    rate: int

    @property
    def fps(self) -> float:
        """Frames per real second: 24, 25, 30000/1001 (29.97 df) or 30."""
        nominal, drop = RATES[self.rate]
        return 30000 / 1001 if drop else float(nominal)

    def problem(self) -> str | None:
        """Why this is not a valid code, or ``None``."""
        nominal, drop = RATES[self.rate]
        if not (self.hours < 24 and self.minutes < 60 and self.seconds < 60):
            return "hours, minutes or seconds out of range"
        if self.frames >= nominal:
            return f"frame {self.frames} at {RATE_NAMES[self.rate]} fps"
        if drop and self.seconds == 0 and self.frames < 2 and self.minutes % 10:
            return f"frame {self.frames} is dropped at the start of minute {self.minutes} (29.97df)"
        return None

    def to_seconds(self) -> float:
        """Real seconds since 00:00:00:00 (drop-frame labels counted as SMPTE drops them)."""
        nominal, drop = RATES[self.rate]
        if not drop:
            return self.hours * 3600 + self.minutes * 60 + self.seconds + self.frames / nominal
        total_min = 60 * self.hours + self.minutes
        n = (3600 * self.hours + 60 * self.minutes + self.seconds) * 30 + self.frames
        n -= 2 * (total_min - total_min // 10)
        return n * 1001 / 30000

    def __str__(self) -> str:
        sep = ";" if RATES[self.rate][1] else ":"
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}{sep}{self.frames:02d}"


@dataclass
class ChasePoll:
    """What one ``poll(t)`` found: the show time (s; ``None`` before a first lock), the state
    (``waiting``, ``locked``, ``freewheel``, ``held``, ``cued``), the last code and events."""

    show_time_s: float | None
    state: str
    timecode: Smpte | None
    events: list[LiveEvent] = field(default_factory=list)


class TimecodeChase:
    """A timecode -> show time: lock, freewheel, hold, relock (MTC's and LTC's one logic).

    A subclass hands each decoded code to :meth:`_new_code` with the local time it was on the
    wire (and how many frames after its label that is), marks the stream alive with
    ``_alive_t``, and calls :meth:`_advance` once per poll for the stop, freewheel and hold.

    Args:
        freewheel_s: how long (s, ≥ 0) the show time runs on after the timecode stops
            (at least one frame).
        jump_s: a new code further than this (s, > 0) from the running show time is a jump.
        offset_s: the timecode that is show time 0 (s; e.g. 3600 for 01:00:00:00).
        capacity: the inbox's size (messages).
        source: the events' ``source``.
    """

    #: the name in messages (``"MTC chase: ..."``)
    name = "MTC"
    #: ``timecode_stopped``'s key for the last sign of life
    alive_key = "last_quarter_frame_t"

    def __init__(
        self,
        *,
        freewheel_s: float = 0.5,
        jump_s: float = 0.1,
        offset_s: float = 0.0,
        capacity: int = DEFAULT_CAPACITY,
        source: str = "mtc",
    ) -> None:
        for name, x, bound in (("freewheel_s", freewheel_s, ">= 0"), ("jump_s", jump_s, "> 0")):
            if (
                isinstance(x, bool)
                or not isinstance(x, int | float)
                or not (0 <= x < math.inf)
                or (name == "jump_s" and x == 0)
            ):
                raise ValueError(
                    f"{self.name} chase: {name} must be a number of seconds {bound}, got {x!r}"
                )
        if (
            isinstance(offset_s, bool)
            or not isinstance(offset_s, int | float)
            or not math.isfinite(offset_s)
        ):
            raise ValueError(
                f"{self.name} chase: offset_s must be a finite number, got {offset_s!r}"
            )
        self.freewheel_s = float(freewheel_s)
        self.jump_s = float(jump_s)
        self.offset_s = float(offset_s)
        self.source = source
        self.inbox = Inbox(capacity)
        self.state = "waiting"
        self.timecode: Smpte | None = None
        self._anchor_show = 0.0  # show time at _anchor_t (s)
        self._anchor_t = 0.0
        self._alive_t = 0.0  # the last sign of the chased stream (local s)
        self._held = 0.0
        self._frame_s = 1 / 24  # one frame (s) at the chased rate; 24 fps until known
        self._bad_run = False
        self.codes = 0  #: codes decoded
        self.rejected = 0  #: messages or codes refused

    def _stale_s(self) -> float:
        """No sign of the stream this long (s): it stopped (MTC: one frame)."""
        return self._frame_s

    def show_time(self, t: float) -> float | None:
        """The show time (s) at local time ``t`` by the current state (no messages applied)."""
        if self.state == "waiting":
            return None
        if self.state in ("held", "cued"):
            return self._held
        return self._running(t)

    def _running(self, t: float) -> float:
        """The show time at ``t`` while the timecode runs (locked, or freewheeling on)."""
        run_on = max(self.freewheel_s, self._frame_s)
        return self._anchor_show + (min(t, self._alive_t + run_on) - self._anchor_t)

    def _advance(self, t: float, events: list[LiveEvent]) -> None:
        """Locked with no sign of the stream for :meth:`_stale_s`: freewheel; then hold."""
        if self.state == "locked" and t - self._alive_t > self._stale_s():
            self.state = "freewheel"
            events.append(
                LiveEvent(
                    t,
                    "timecode_stopped",
                    self.source,
                    {
                        self.alive_key: self._alive_t,
                        "freewheel_s": self.freewheel_s,
                        "message": f"{self.name} stopped: the show time runs on "
                        f"{max(self.freewheel_s, self._frame_s):g} s, then holds",
                    },
                )
            )
        if self.state == "freewheel" and t - self._alive_t >= max(self.freewheel_s, self._frame_s):
            self._held = self._running(t)  # (freewheel: what show_time(t) gives)
            self.state = "held"
            message = f"{self.name} gone: the show time holds at {self._held:.3f} s"
            events.append(
                LiveEvent(
                    t,
                    "timecode_held",
                    self.source,
                    {"show_time_s": self._held, "message": message},
                )
            )

    def _new_code(
        self, tm: float, code: Smpte, frames_late: float, cause: str, events: list[LiveEvent]
    ) -> None:
        why = code.problem()
        if why is not None:
            self.rejected += 1
            if not self._bad_run:  # one event per run of bad codes, not one every 2 frames
                events.append(
                    LiveEvent(
                        tm,
                        "timecode_invalid",
                        self.source,
                        {
                            "timecode": str(code),
                            "problem": why,
                            "message": f"{self.name}: {code} is no valid code: {why}",
                        },
                    )
                )
            self._bad_run = True
            return
        self._bad_run = False
        self.codes += 1
        self._frame_s = 1 / code.fps
        new = code.to_seconds() + frames_late * self._frame_s - self.offset_s
        before = self.show_time(tm)
        rate = RATE_NAMES[code.rate]
        detail: dict[str, Any] = {
            "timecode": str(code),
            "rate": rate,
            "show_time_s": new,
            "offset_s": self.offset_s,
        }
        if cause == "quarter_frames":
            detail["quarter_frame"] = 7  # the piece that completed the code: the anchor
        if self.timecode is not None and code.rate != self.timecode.rate:
            detail["rate_was"] = RATE_NAMES[self.timecode.rate]
        if before is not None and abs(new - before) > self.jump_s:
            events.append(
                LiveEvent(
                    tm,
                    "timecode_jump",
                    self.source,
                    {
                        **detail,
                        "from_s": before,
                        "to_s": new,
                        "cause": cause,
                        "message": f"{self.name} jumped to {code}: show time {before:.3f} -> "
                        f"{new:.3f} s",
                    },
                )
            )
        self.timecode = code
        if cause == "full_frame":
            self.state, self._held = "cued", new
            events.append(LiveEvent(tm, "timecode_locate", self.source, detail))
            return
        if self.state != "locked":
            said = (
                f"{self.name} locked at {code} ({rate} fps): show time {new:.3f} s "
                f"(offset {self.offset_s:g} s)"
            )
            events.append(
                LiveEvent(tm, "timecode_locked", self.source, {**detail, "message": said})
            )
        elif "rate_was" in detail:
            events.append(LiveEvent(tm, "timecode_rate", self.source, detail))
        self.state = "locked"
        self._anchor_show, self._anchor_t, self._alive_t = new, tm, tm


class MtcChase(TimecodeChase):
    """MIDI Time Code -> show time (see the module docstring); the arguments are
    :class:`TimecodeChase`'s."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._pieces = [0] * 8
        self._last_piece = -1  # the last quarter frame's piece
        self._in_sequence = False  # pieces 0.. arrived in order, without a pause
        self._last_qf_t = -math.inf
        self._reverse_run = 0
        self.quarter_frames = 0  #: quarter frames received
        self.codes = 0  #: full codes decoded (quarter-frame sequences and full frames)
        self.rejected = 0  #: quarter frames out of sequence, invalid codes, other messages

    def feed(self, message: Any, t: float) -> None:
        """Hand in one MIDI message stamped ``t`` (show time of the loop's clock, s)."""
        self.inbox.put(t, message)

    def poll(self, t: float) -> ChasePoll:
        """Apply the messages due at ``t`` and advance the state; bounded work, never waits."""
        events: list[LiveEvent] = []
        drops = self.inbox.take_drops()
        if drops:
            events.append(
                LiveEvent(
                    t,
                    "inbox_overflow",
                    self.source,
                    {"dropped": drops, "total": self.inbox.dropped},
                )
            )
        for tm, msg in self.inbox.take_due(t):
            kind = getattr(msg, "type", None)
            if kind == "quarter_frame":
                self._quarter_frame(tm, int(msg.frame_type) & 7, int(msg.frame_value) & 15, events)
            elif kind == "sysex":
                self._full_frame(tm, tuple(msg.data), events)
            else:
                self.rejected += 1
        self._advance(t, events)
        return ChasePoll(self.show_time(t), self.state, self.timecode, events)

    def _quarter_frame(self, tm: float, piece: int, nibble: int, events: list[LiveEvent]) -> None:
        self.quarter_frames += 1
        stale = tm - self._last_qf_t > 2 * self._frame_s  # a pause: a sequence starts again
        self._last_qf_t = tm
        last = -1 if stale else self._last_piece
        self._last_piece = piece
        if last >= 0 and piece == (last - 1) % 8:  # counting down: a sender rewinding
            self._reverse_run += 1
            if self._reverse_run == 8:
                note = "reverse quarter frames are not chased: freewheel, then hold"
                events.append(LiveEvent(tm, "timecode_reverse", self.source, {"note": note}))
            self._in_sequence = False
            self.rejected += 1
            return
        self._reverse_run = 0
        if piece == 0:
            self._in_sequence = True
        elif not (self._in_sequence and last == piece - 1):
            self._in_sequence = False
            self.rejected += 1
            return
        if self.state == "locked":
            self._alive_t = tm
        self._pieces[piece] = nibble
        if piece == 7:
            self._in_sequence = False
            p = self._pieces
            code = Smpte(
                hours=p[6] | (p[7] & 1) << 4,
                minutes=p[4] | (p[5] & 3) << 4,
                seconds=p[2] | (p[3] & 3) << 4,
                frames=p[0] | (p[1] & 1) << 4,
                rate=(p[7] >> 1) & 3,
            )
            self._new_code(tm, code, 1.75, "quarter_frames", events)

    def _full_frame(self, tm: float, data: tuple[int, ...], events: list[LiveEvent]) -> None:
        # F0 7F <device> 01 01 hr mn sc fr F7; mido's data is the bytes between F0 and F7
        if len(data) != 8 or data[0] != 0x7F or data[2:4] != (0x01, 0x01):
            self.rejected += 1
            return
        hr, mn, sc, fr = data[4:8]
        code = Smpte(hr & 0x1F, mn & 0x3F, sc & 0x3F, fr & 0x1F, (hr >> 5) & 3)
        self._new_code(tm, code, 0.0, "full_frame", events)
