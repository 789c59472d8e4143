"""Lip-sync files -> mouth-shape cues -> step-hold joint tracks.

Readers return :class:`Cues`, (time, shape) in order with each cue's file position:
:func:`read_rhubarb_tsv`, :func:`read_rhubarb_json`, :func:`read_rhubarb_xml` (Rhubarb Lip
Sync), :func:`read_moho_dat` (Moho switch files, at the rig's fps) and :func:`read_papagayo`
(``.pgo``); :func:`read_cues` picks one by the file's suffix.

Shapes are Rhubarb's letters A-H and X, or Preston Blair phoneme names; "E" means different
mouths in the two, so every :class:`Cues` says which vocabulary it holds. A :class:`ShapeTable`
maps shapes to values (by default Blair names through Rhubarb's own correspondence,
:data:`PRESTON_BLAIR_TO_RHUBARB`). A shape the table lacks is a FormatError naming the line.

The rig's use, per joint::

    track = cue_track(read_cues(path, fps=..., names=..., voice=...),
                      ShapeTable(rhubarb={...}, preston_blair={...}),
                      UnitMap((0, 1), (closed_deg, open_deg), "opening"))

Each file's layout, the vocabularies and Papagayo's timing: ``docs/targets.md`` (Lip-sync).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from hilsim.targets.formats.common import FormatError, SampledTrack, UnitMap
from hilsim.targets.formats.lipsync_cues import (
    BLAIR_ONLY,
    MAX_FPS,
    PRESTON_BLAIR,
    PRESTON_BLAIR_TO_RHUBARB,
    RHUBARB_ONLY,
    RHUBARB_SHAPES,
    VOCABULARIES,
    Cue,
    Cues,
    frame_number,
    in_order,
    read_rhubarb_json,
    read_rhubarb_tsv,
    read_rhubarb_xml,
    shape_word,
    text_lines,
)

__all__ = [
    "PRESTON_BLAIR",
    "PRESTON_BLAIR_TO_RHUBARB",
    "RHUBARB_SHAPES",
    "Cue",
    "Cues",
    "ShapeTable",
    "cue_track",
    "read_cues",
    "read_moho_dat",
    "read_papagayo",
    "read_rhubarb_json",
    "read_rhubarb_tsv",
    "read_rhubarb_xml",
]


@dataclass(frozen=True)
class ShapeTable:
    """The rig's values per mouth shape (see the module's docstring). ValueError names an
    entry that is not a finite number (or, in ``preston_blair``, a Rhubarb letter)."""

    rhubarb: Mapping[str, float] = field(default_factory=dict)
    preston_blair: Mapping[str, float | str] = field(default_factory=dict)
    _blair: dict[str, float | str] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name, number in self.rhubarb.items():
            if name not in RHUBARB_SHAPES:
                raise ValueError(
                    f"rhubarb: {name!r} is not a Rhubarb shape ({', '.join(RHUBARB_SHAPES)})"
                )
            _number(f"rhubarb.{name}", number)
        blair: dict[str, float | str] = {k.lower(): v for k, v in PRESTON_BLAIR_TO_RHUBARB.items()}
        for name, value in self.preston_blair.items():
            if not isinstance(name, str) or not name or name.split() != [name]:
                raise ValueError(f"preston_blair: {name!r} is not a phoneme name")
            if isinstance(value, str):
                if value not in RHUBARB_SHAPES:
                    raise ValueError(
                        f"preston_blair.{name} = {value!r}: a number or a Rhubarb shape "
                        f"({', '.join(RHUBARB_SHAPES)})"
                    )
            else:
                _number(f"preston_blair.{name}", value)
            blair[name.lower()] = value
        object.__setattr__(self, "rhubarb", dict(self.rhubarb))
        object.__setattr__(self, "_blair", blair)

    def value(self, shape: str, vocabulary: str) -> float:
        """The table's value for ``shape``; KeyError with the reason when it has none."""
        if vocabulary == "rhubarb":
            if shape in self.rhubarb:
                return float(self.rhubarb[shape])
            raise KeyError(f"Rhubarb shape {shape!r} is not in the rig's table ({self._has()})")
        value = self._blair.get(shape.lower())
        if value is None:
            raise KeyError(
                f"phoneme {shape!r} is not in the rig's table (Preston Blair names: "
                f"{', '.join(sorted(self._blair))}; add it to preston_blair)"
            )
        if isinstance(value, str):
            if value not in self.rhubarb:
                raise KeyError(
                    f"phoneme {shape!r} is Rhubarb shape {value!r}, which the rig's table "
                    f"does not have ({self._has()})"
                )
            return float(self.rhubarb[value])
        return float(value)

    def _has(self) -> str:
        return "has " + (", ".join(self.rhubarb) or "no Rhubarb shapes")


def _number(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{name} = {value!r}: must be a finite number")


# ------------------------------------------------------------------------------ the track


def cue_track(cues: Cues, table: ShapeTable, unit: UnitMap) -> SampledTrack:
    """A step-hold track: each cue's table value through ``unit`` (to degrees), held until
    the next cue; held after the last (its duration is ``end_s`` when the file gives it).
    Cues at one time: the last one counts. FormatError names the line of an unknown shape."""
    times: list[float] = []
    values: list[float] = []
    for cue in cues.cues:
        try:
            v = table.value(cue.shape, cues.vocabulary)
        except KeyError as exc:
            raise FormatError(cues.path, cue.where, exc.args[0]) from None
        if times and times[-1] == cue.time_s:
            values[-1] = v
        else:
            times.append(cue.time_s)
            values.append(v)
    if not times:
        raise FormatError(cues.path, "", "no mouth cues")
    if cues.end_s is not None and cues.end_s > times[-1]:
        times.append(cues.end_s)
        values.append(values[-1])
    return SampledTrack(times, unit.to_rad(values), "hold", source=f"{cues.path} (lip-sync)")


# ------------------------------------------------------------------------------ Moho, Papagayo


def _fps(fps: object) -> float:
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps <= MAX_FPS:
        raise ValueError(f"fps = {fps!r}: must be a number > 0 and <= {MAX_FPS:g}")
    return float(fps)


def read_moho_dat(path: str | Path, fps: float, names: str = "auto") -> Cues:
    """A Moho switch file: ``MohoSwitch1``, then ``<frame> <shape>`` (1-based frames) at the
    rig's ``fps``. ``names``: ``"rhubarb"``, ``"preston_blair"`` or ``"auto"``: told by the
    names the file uses (other phoneme names go to the table's ``preston_blair`` part); a
    file whose only known shape is "E" must be told."""
    rate = _fps(fps)
    if names not in ("auto", *VOCABULARIES):
        raise ValueError(f"names = {names!r}: allowed auto, {', '.join(VOCABULARIES)}")
    _, lines = text_lines(path)
    if lines[0].strip() != "MohoSwitch1":
        raise FormatError(
            path, "line 1", f"not a Moho switch file: expected 'MohoSwitch1', got {lines[0][:40]!r}"
        )
    cues: list[Cue] = []
    for i, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        parts = line.split()
        where = f"line {i}"
        if len(parts) != 2:
            raise FormatError(path, where, f"expected '<frame> <shape>', got {line[:60]!r}")
        frame = frame_number(path, where, parts[0], "frame", low=1)
        cues.append(Cue((frame - 1) / rate, shape_word(path, where, parts[1]), where))
    if not cues:
        raise FormatError(path, "", "no cues after 'MohoSwitch1'")
    in_order(path, cues)
    return Cues(str(path), tuple(cues), _vocabulary(path, cues) if names == "auto" else names)


def _vocabulary(path: str | Path, cues: list[Cue]) -> str:
    blair = next((c for c in cues if c.shape.lower() in BLAIR_ONLY), None)
    letter = next((c for c in cues if c.shape in RHUBARB_ONLY), None)
    if blair and letter:
        raise FormatError(
            path,
            "",
            f"mixes Rhubarb shapes ({letter.where}: {letter.shape!r}) and Preston Blair "
            f"names ({blair.where}: {blair.shape!r}); one file holds one kind",
        )
    if letter:
        return "rhubarb"
    if blair or not any(c.shape == "E" for c in cues):
        return "preston_blair"
    raise FormatError(
        path,
        "",
        "its shapes do not tell Rhubarb's letters from Preston Blair names (E is in "
        "both): say names = rhubarb or preston_blair",
    )


_Word = tuple[int, int, list[tuple[int, str, str]]]  # start, end (inclusive), phonemes


def read_papagayo(path: str | Path, voice: str | int | None = None) -> Cues:
    """A Papagayo ``.pgo``: the phonemes of one voice (by name or 0-based index; a file of one
    voice needs none), ``rest`` before and between words, times frame/fps."""
    _, lines = text_lines(path)
    pos = 0

    def take(what: str) -> tuple[str, str]:
        nonlocal pos
        if pos >= len(lines):
            raise FormatError(path, f"line {pos + 1}", f"the file ends where {what} should be")
        pos += 1
        return lines[pos - 1].strip(), f"line {pos}"

    def number(what: str) -> int:
        text, where = take(what)
        return frame_number(path, where, text, what.removeprefix("a ").removeprefix("the "))

    head, where = take("the header")
    if head != "lipsync version 1":
        raise FormatError(
            path, where, f"not a Papagayo file: expected 'lipsync version 1', got {head[:40]!r}"
        )
    take("the sound file's path")
    fps = number("the frame rate")
    if not 1 <= fps <= MAX_FPS:
        raise FormatError(path, f"line {pos}", f"frame rate {fps}: allowed 1 .. {MAX_FPS:g}")
    duration = number("the duration in frames")
    voices: list[tuple[str, list[_Word]]] = []
    for _v in range(number("the number of voices")):
        name, _ = take("a voice's name")
        take("a voice's text")
        words: list[_Word] = []
        for _p in range(number("a number of phrases")):
            take("a phrase's text")
            number("a phrase's start frame")
            number("a phrase's end frame")
            for _w in range(number("a number of words")):
                words.append(_word(path, take))
        voices.append((name, words))
    chosen = _choose_voice(path, voices, voice)
    cues: list[Cue] = [Cue(0.0, "rest", "frame 0 (rest before the first word)")]
    last_end = -1
    for start, end, phonemes in chosen:
        if start <= last_end:
            raise FormatError(
                path,
                phonemes[0][2] if phonemes else "",
                f"a word starts at frame {start}, before the word above ends ({last_end})",
            )
        if start > last_end + 1 and last_end >= 0:
            cues.append(Cue((last_end + 1) / fps, "rest", f"frame {last_end + 1} (rest)"))
        for frame, shape, where in phonemes:
            cues.append(Cue(frame / fps, shape, where))
        last_end = end
    if last_end >= 0:
        cues.append(Cue((last_end + 1) / fps, "rest", f"frame {last_end + 1} (rest)"))
    in_order(path, cues)
    end_s = max(duration / fps, cues[-1].time_s)
    return Cues(str(path), tuple(cues), "preston_blair", end_s)


def _word(path: str | Path, take: Callable[[str], tuple[str, str]]) -> _Word:
    line, where = take("a word")
    parts = line.split()
    if len(parts) != 4:
        raise FormatError(
            path, where, f"expected '<word> <start> <end> <phonemes>', got {line[:60]!r}"
        )
    start = frame_number(path, where, parts[1], "word start frame")
    end = frame_number(path, where, parts[2], "word end frame")
    if end < start:
        raise FormatError(path, where, f"the word ends (frame {end}) before it starts ({start})")
    phonemes: list[tuple[int, str, str]] = []
    for _ in range(frame_number(path, where, parts[3], "number of phonemes")):
        line, at = take("a phoneme")
        bits = line.split()
        if len(bits) != 2:
            raise FormatError(path, at, f"expected '<frame> <phoneme>', got {line[:60]!r}")
        frame = frame_number(path, at, bits[0], "phoneme frame")
        if not start <= frame <= end:
            raise FormatError(
                path, at, f"phoneme at frame {frame}, outside its word's frames {start}..{end}"
            )
        if phonemes and frame < phonemes[-1][0]:
            raise FormatError(
                path, at, f"phoneme at frame {frame} comes before the one above ({phonemes[-1][0]})"
            )
        phonemes.append((frame, shape_word(path, at, bits[1]), at))
    return start, end, phonemes


def _choose_voice(
    path: str | Path, voices: list[tuple[str, list[_Word]]], voice: str | int | None
) -> list[_Word]:
    names = [name for name, _ in voices]
    if voice is None:
        if len(voices) == 1:
            return voices[0][1]
        raise FormatError(
            path,
            "",
            f"{len(voices)} voices ({', '.join(names) or 'none'}): say which "
            "(voice = name or index)",
        )
    if isinstance(voice, int) and not isinstance(voice, bool) and 0 <= voice < len(voices):
        return voices[voice][1]
    if isinstance(voice, str) and voice in names:
        return voices[names.index(voice)][1]
    raise FormatError(path, "", f"no voice {voice!r}; the file has {', '.join(names) or 'none'}")


SUFFIXES = {
    ".tsv": "tsv",
    ".txt": "tsv",
    ".json": "json",
    ".xml": "xml",
    ".dat": "dat",
    ".pgo": "pgo",
}


def read_cues(
    path: str | Path,
    *,
    fps: float | None = None,
    names: str = "auto",
    voice: str | int | None = None,
    kind: str | None = None,
) -> Cues:
    """Any of the readers, chosen by ``kind`` (tsv json xml dat pgo) or the file's suffix.
    ``fps`` is needed for a Moho .dat only."""
    kind = kind or SUFFIXES.get(Path(path).suffix.lower())
    if kind == "dat":
        if fps is None:
            raise ValueError("a Moho .dat file holds no frame rate: give fps")
        return read_moho_dat(path, fps, names)
    readers = {"tsv": read_rhubarb_tsv, "json": read_rhubarb_json, "xml": read_rhubarb_xml}
    if kind in readers:
        return readers[kind](path)
    if kind == "pgo":
        return read_papagayo(path, voice)
    kinds = ", ".join(sorted(set(SUFFIXES.values())))
    raise ValueError(
        f"{path}: lip-sync kind {kind!r}; allowed {kinds} (or a file ending {', '.join(SUFFIXES)})"
    )
