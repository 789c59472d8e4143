"""Standard MIDI Files (``.mid``, format 0 and 1) as tracks in joint radians: control changes
and notes to joints, with the words live MIDI uses (``channel`` 1-16, ``control``, ``fine``).

The rig's use is one call per joint::

    seq = read_midi_file(path)
    pan = seq.cc_track(channel=1, control=7, degrees=(-30, 30), interpolation="hold")
    blink = seq.note_track(channel=10, note=60, degrees=(0, 25))

**Time.** Ticks become seconds through the tempo map: every Set Tempo meta event of every track
(format 1 keeps them in the first, but one anywhere counts, as a player merges the tracks), from
120 bpm until the first one; at one tick the last in file order wins. A PPQN division is ticks
per quarter note; an SMPTE division (frames per second, ticks per frame) is absolute time, and
its tempo events move nothing. Format 2 (independent sequences) is refused in one line.

**Values** are as :class:`hilsim.live.midi.CcMapping` makes them live: value 0 -> ``degrees[0]``,
127 -> ``degrees[1]``; ``fine``: control (0-31) is a 14-bit pair's MSB and control + 32 its LSB
(an MSB resets the LSB, an LSB before any MSB is ignored). A note is ``degrees[1]`` from its
note-on (velocity > 0) to its note-off (or note-on velocity 0), else ``degrees[0]``.

Every bad input is one :class:`~hilsim.targets.formats.common.FormatError` naming the file and
the byte. No chunk length is trusted before it is checked against the file's size. The reader
is ours (no mido needed to read a file); the tests write their files with mido.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from hilsim.targets.formats.common import (
    INTERPOLATIONS,
    FormatError,
    SampledTrack,
    UnitMap,
    read_bytes,
)

#: a quarter note's length until the first Set Tempo (µs; 120 bpm)
DEFAULT_TEMPO_US = 500_000
#: SMPTE division: the header's high byte (negative) -> frames per second
SMPTE_FPS = {-24: 24.0, -25: 25.0, -29: 30000 / 1001, -30: 30.0}
NOTE_OFF, NOTE_ON, CONTROL_CHANGE = 0x80, 0x90, 0xB0
_KEPT = frozenset((NOTE_OFF, NOTE_ON, CONTROL_CHANGE))


class ChannelEvent(NamedTuple):
    """A note or a control change: ``tick`` (absolute), ``kind`` (status high nibble),
    ``channel`` 1-16, ``number`` (note or controller), ``value`` (velocity or value)."""

    tick: int
    kind: int
    channel: int
    number: int
    value: int


@dataclass
class MidiSequence:
    """What a file holds that a joint can use (see the module docstring).

    ``events``: notes and control changes of every track, merged in time order (at one tick,
    by track then file order); ``tempos``: ``(tick, µs per quarter)`` in force from each tick;
    ``end_tick``: the last End of Track (or event). ``division``: ticks per quarter (PPQN), or
    ``(fps, ticks per frame)`` for SMPTE.
    """

    path: str
    format: int
    division: int | tuple[float, int]
    events: list[ChannelEvent]
    tempos: list[tuple[int, int]] = field(default_factory=list)
    end_tick: int = 0
    tracks: int = 1

    def seconds(self, ticks: Iterable[int]) -> np.ndarray:
        """Ticks -> show seconds through the tempo map (or the SMPTE rate)."""
        tk = np.asarray(list(ticks), dtype=np.float64)
        if isinstance(self.division, tuple):
            fps, per_frame = self.division
            return tk / (fps * per_frame)
        starts = np.array([0] + [t for t, _ in self.tempos], dtype=np.float64)
        tempo = np.array([DEFAULT_TEMPO_US] + [u for _, u in self.tempos], dtype=np.float64)
        s_per_tick = tempo * 1e-6 / self.division
        at = np.concatenate(([0.0], np.cumsum(np.diff(starts) * s_per_tick[:-1])))
        i = np.searchsorted(starts, tk, side="right") - 1
        return at[i] + (tk - starts[i]) * s_per_tick[i]

    @property
    def duration_s(self) -> float:
        """The file's length: its last End of Track, in s."""
        return float(self.seconds([self.end_tick])[0])

    def describe(self) -> str:
        """The file's timing in one line, for the rig's notes: ``format 1, 3 tracks, 480 ticks
        per quarter note, 120 bpm, 60 bpm from 2.000 s; 10.000 s``."""
        tracks = f"{self.tracks} track{'s' * (self.tracks != 1)}"
        if isinstance(self.division, tuple):
            fps, per_frame = self.division
            timing = f"SMPTE {fps:.5g} fps x {per_frame} ticks (tempo events move nothing)"
        else:
            changes = [(t, u) for t, u in self.tempos if t > 0]
            first = next((u for t, u in self.tempos if t == 0), DEFAULT_TEMPO_US)
            at = self.seconds([t for t, _ in changes])
            bpm = [f"{6e7 / first:.6g} bpm"] + [
                f"{6e7 / u:.6g} bpm from {s:.3f} s"
                for (_, u), s in zip(changes[:3], at, strict=False)
            ]
            if len(changes) > 3:
                bpm.append(f"{len(changes) - 3} more tempo changes")
            timing = f"{self.division} ticks per quarter note, " + ", ".join(bpm)
        return f"format {self.format}, {tracks}, {timing}; {self.duration_s:.3f} s"

    def contents(self) -> str:
        """What the file has, for a message: ``ch1 cc 7, 10; ch10 notes 36, 38``."""
        cc: dict[int, set[int]] = {}
        notes: dict[int, set[int]] = {}
        for e in self.events:
            (cc if e.kind == CONTROL_CHANGE else notes).setdefault(e.channel, set()).add(e.number)
        parts = [f"ch{c} cc {', '.join(map(str, sorted(n)))}" for c, n in sorted(cc.items())]
        parts += [f"ch{c} notes {', '.join(map(str, sorted(n)))}" for c, n in sorted(notes.items())]
        return "; ".join(parts) or "no notes or control changes"

    def cc_track(
        self,
        channel: int,
        control: int,
        degrees: tuple[float, float],
        *,
        fine: bool = False,
        interpolation: str = "hold",
    ) -> SampledTrack:
        """The joint a controller drives: each value held until the next (``"hold"``, as a live
        controller is) or joined (``"linear"``); the first value held before it, the last after
        it until the file's end."""
        if interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"interpolation must be {' or '.join(INTERPOLATIONS)}, got {interpolation!r}"
            )
        ticks, raws = [], []
        raw: int | None = None
        for e in self.events:
            if e.kind != CONTROL_CHANGE or e.channel != channel:
                continue
            if e.number == control:
                raw = e.value << 7 if fine else e.value  # an MSB resets the LSB (MIDI 1.0)
            elif fine and e.number == control + 32 and raw is not None:
                raw = (raw & ~0x7F) | e.value
            else:
                continue
            ticks.append(e.tick)
            raws.append(raw)
        if not ticks:
            pair = f" (14-bit, LSB {control + 32})" if fine else ""
            raise FormatError(
                self.path,
                "",
                f"no control change {control}{pair} on channel {channel}; it has "
                + self.contents(),
            )
        umap = UnitMap((0, 16383 if fine else 127), degrees, "MIDI value")
        return self._track(ticks, umap.to_rad(raws), interpolation, f"ch{channel} cc {control}")

    def note_track(self, channel: int, note: int, degrees: tuple[float, float]) -> SampledTrack:
        """The joint a note drives: ``degrees[1]`` while it sounds, ``degrees[0]`` else
        (before its first note-on too); held, never joined (a note is a step)."""
        ticks, on = [0], [False]
        seen = False
        for e in self.events:
            if e.channel != channel or e.number != note or e.kind == CONTROL_CHANGE:
                continue
            seen = True
            ticks.append(e.tick)
            on.append(e.kind == NOTE_ON and e.value > 0)
        if not seen:
            raise FormatError(
                self.path, "", f"no note {note} on channel {channel}; it has " + self.contents()
            )
        deg = np.where(on, degrees[1], degrees[0])
        return self._track(ticks, np.radians(deg), "hold", f"ch{channel} note {note}")

    def _track(
        self, ticks: list[int], rad: np.ndarray, interpolation: str, what: str
    ) -> SampledTrack:
        """Samples at ticks (several at one tick: the last wins), held to the file's end."""
        ticks = [*ticks, max(self.end_tick, ticks[-1])]
        rad = np.append(rad, rad[-1])
        t = self.seconds(ticks)
        last = np.append(np.diff(t) > 0, True)  # the last sample of each instant
        t, v = t[last], rad[last]
        return SampledTrack(t, v, interpolation, f"{Path(self.path).name} {what}")


class _Reader:
    """Bytes of one file with FormatErrors that name it and the byte."""

    def __init__(self, data: bytes, path: str) -> None:
        self.data, self.path = data, path

    def bad(self, pos: int, message: str) -> FormatError:
        return FormatError(self.path, f"byte {pos}", message)

    def vlq(self, pos: int, end: int, track: int, what: str) -> tuple[int, int]:
        """A variable-length quantity at ``pos`` (at most 4 bytes) -> (value, next pos);
        ``what`` names it in an error (``a delta time``) of ``track``."""
        if pos < end and self.data[pos] < 0x80:  # one byte: most delta times
            return self.data[pos], pos + 1
        what = f"track {track}: {what}"
        value = 0
        for i in range(4):
            if pos + i >= end:
                raise self.bad(pos, f"{what} cut short by the end of the track")
            b = self.data[pos + i]
            value = (value << 7) | (b & 0x7F)
            if not b & 0x80:
                return value, pos + i + 1
        raise self.bad(pos, f"{what} is longer than 4 bytes (not a MIDI variable-length number)")


def read_midi_file(path: str | Path) -> MidiSequence:
    """Read a Standard MIDI File (format 0 or 1). Raises FormatError naming the file and byte."""
    data = read_bytes(path)
    r = _Reader(data, str(path))
    if data[:4] != b"MThd":
        hint = " (a RIFF .rmi: export a plain .mid)" if data[:4] == b"RIFF" else ""
        raise r.bad(0, f"not a Standard MIDI File: it does not start with MThd{hint}")
    if len(data) < 14:
        raise r.bad(len(data), "the header chunk is cut short (14 bytes needed)")
    size = int.from_bytes(data[4:8], "big")
    fmt, ntrks, div = (int.from_bytes(data[i : i + 2], "big") for i in (8, 10, 12))
    if size < 6 or 8 + size > len(data):
        raise r.bad(4, f"header length {size} is not 6 or more within the file")
    if fmt == 2:
        raise r.bad(8, "format 2 (independent sequences) is not read: save it as format 0 or 1")
    if fmt not in (0, 1):
        raise r.bad(8, f"unknown format {fmt} (0 and 1 are read)")
    if ntrks == 0 or (fmt == 0 and ntrks != 1):
        raise r.bad(10, f"format {fmt} with {ntrks} tracks")
    division: int | tuple[float, int]
    if div & 0x8000:
        code = (div >> 8) - 256
        if code not in SMPTE_FPS or not div & 0xFF:
            raise r.bad(12, f"SMPTE division {code} fps, {div & 0xFF} ticks per frame")
        division = (SMPTE_FPS[code], div & 0xFF)
    elif div == 0:
        raise r.bad(12, "0 ticks per quarter note")
    else:
        division = div
    seq = MidiSequence(str(path), fmt, division, [], tracks=ntrks)
    found: list[tuple[int, int, int, ChannelEvent]] = []
    tempos: list[tuple[int, int, int, int]] = []
    pos = 8 + size
    track = 0
    while track < ntrks:
        if pos + 8 > len(data):
            raise r.bad(pos, f"the header says {ntrks} tracks; the file ends after {track}")
        kind, length = data[pos : pos + 4], int.from_bytes(data[pos + 4 : pos + 8], "big")
        start, end = pos + 8, pos + 8 + length
        if end > len(data):
            raise r.bad(pos, f"track {track + 1}: {length} bytes said, {len(data) - start} left")
        if kind == b"MTrk":
            track += 1
            last = _read_track(r, start, end, track, found, tempos)
            seq.end_tick = max(seq.end_tick, last)
        pos = end  # a chunk of another kind is skipped, as the standard asks
    found.sort(key=lambda x: x[:3])
    seq.events = [e for *_, e in found]
    tempos.sort()
    seq.tempos = [(tick, us) for tick, _, _, us in tempos]
    return seq


def _read_track(
    r: _Reader,
    pos: int,
    end: int,
    track: int,
    found: list[tuple[int, int, int, ChannelEvent]],
    tempos: list[tuple[int, int, int, int]],
) -> int:
    """Append the track's notes, control changes and tempos; return its last tick."""
    data, tick, status, n = r.data, 0, 0, 0
    where = f"track {track}"
    while pos < end:
        delta, pos = r.vlq(pos, end, track, "a delta time")
        tick += delta
        if pos >= end:
            raise r.bad(pos, f"{where}: an event cut short by the end of the track")
        b = data[pos]
        # meta and SysEx events cancel running status in the standard; a data byte after one
        # is read with the last channel status, as lenient players do (a valid file has none)
        if b == 0xFF:  # meta event: type, length, data
            if pos + 1 >= end:
                raise r.bad(pos, f"{where}: a meta event cut short by the end of the track")
            meta = data[pos + 1]
            length, body = r.vlq(pos + 2, end, track, "a meta event's length")
            if body + length > end:
                raise r.bad(pos, f"{where}: a meta event of {length} bytes runs past the track")
            if meta == 0x51:
                if length != 3:
                    raise r.bad(pos, f"{where}: Set Tempo must hold 3 bytes, it holds {length}")
                us = int.from_bytes(data[body : body + 3], "big")
                if us == 0:
                    raise r.bad(pos, f"{where}: Set Tempo of 0 µs per quarter note")
                tempos.append((tick, track, n, us))
            pos, n = body + length, n + 1
            if meta == 0x2F:  # End of Track
                return tick
            continue
        if b in (0xF0, 0xF7):  # SysEx (or its continuation): length, data
            length, body = r.vlq(pos + 1, end, track, "a SysEx length")
            if body + length > end:
                raise r.bad(pos, f"{where}: a SysEx of {length} bytes runs past the track")
            pos = body + length
            continue
        if b & 0x80:
            if b >= 0xF0:
                raise r.bad(pos, f"{where}: status 0x{b:02X} is not an event of a MIDI file")
            status, pos = b, pos + 1
        elif not status:
            raise r.bad(pos, f"{where}: data byte 0x{b:02X} with no status before it")
        kind = status & 0xF0
        size = 1 if kind in (0xC0, 0xD0) else 2
        if pos + size > end:
            raise r.bad(pos, f"{where}: an event cut short by the end of the track")
        a = data[pos]
        b = data[pos + size - 1]
        if (a | b) & 0x80:
            raise r.bad(pos, f"{where}: a data byte over 127 in a 0x{status:02X} event")
        if kind in _KEPT:
            found.append((tick, track, n, ChannelEvent(tick, kind, (status & 0x0F) + 1, a, b)))
        pos, n = pos + size, n + 1
    return tick  # no End of Track: the chunk's end is the track's
