"""Mouth-shape cues as the lip-sync readers give them, the text helpers they share, and
Rhubarb Lip Sync's three formats (TSV, JSON, XML). :mod:`hilsim.targets.formats.lipsync` is
the public face: it re-exports these readers and adds Moho, Papagayo, the rig's shape table and
the track.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.parsers import expat

from hilsim.targets.formats.common import FormatError, decode_text, read_bytes

RHUBARB_SHAPES = ("A", "B", "C", "D", "E", "F", "G", "H", "X")
#: Rhubarb's own Preston Blair names for its shapes (its DAT exporter's table)
PRESTON_BLAIR_TO_RHUBARB: dict[str, str] = {
    "MBP": "A", "etc": "B", "E": "C", "AI": "D", "O": "E", "U": "F", "FV": "G", "L": "H",
    "rest": "X",
}  # fmt: skip
PRESTON_BLAIR = (*PRESTON_BLAIR_TO_RHUBARB, "WQ")
VOCABULARIES = ("rhubarb", "preston_blair")
BLAIR_ONLY = {n.lower() for n in PRESTON_BLAIR} - {"e"}
RHUBARB_ONLY = set(RHUBARB_SHAPES) - {"E"}
MAX_FPS = 1000.0


@dataclass(frozen=True)
class Cue:
    """A mouth shape from ``time_s`` on; ``where`` is its place in the file (``line 4``)."""

    time_s: float
    shape: str
    where: str


@dataclass(frozen=True)
class Cues:
    """A file's cues in time order, in one vocabulary (``"rhubarb"`` or ``"preston_blair"``).
    ``end_s``: where the file says the recording ends (the last cue holds until then)."""

    path: str
    cues: tuple[Cue, ...]
    vocabulary: str
    end_s: float | None = None


# ------------------------------------------------------------------------------ text


def text_lines(path: str | Path) -> tuple[str, list[str]]:
    """(the file as text, its lines); FormatError for empty, binary or non-UTF-8 files."""
    text = decode_text(read_bytes(path), path, "a NUL byte: a binary file, not lip-sync text")
    if not text.strip():
        raise FormatError(path, "", "empty file: no mouth cues")
    return text, text.splitlines()


def seconds(path: str | Path, where: str, text: str, what: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError, OverflowError):
        raise FormatError(
            path, where, f"{what} must be a number of seconds, got {text!r}"
        ) from None
    if not math.isfinite(value) or value < 0 or value > 1e7:
        raise FormatError(path, where, f"{what} {text!r}: allowed 0 .. 1e7 s")
    return value


def frame_number(path: str | Path, where: str, text: str, what: str, low: int = 0) -> int:
    if not (text.isascii() and text.isdigit() and len(text) <= 9):
        raise FormatError(path, where, f"{what} must be a whole number, got {text!r}")
    value = int(text)
    if value < low:
        raise FormatError(path, where, f"{what} {value}: allowed {low} or more")
    return value


def in_order(path: str | Path, cues: list[Cue]) -> None:
    for before, cue in itertools.pairwise(cues):
        if cue.time_s < before.time_s:
            raise FormatError(
                path,
                cue.where,
                f"time {cue.time_s:g} s comes before the cue above "
                f"({before.time_s:g} s at {before.where}): cues must be in time order",
            )


def shape_word(path: str | Path, where: str, text: str) -> str:
    shape = text.strip()
    if not shape or shape.split() != [shape] or len(shape) > 64:
        raise FormatError(path, where, f"a mouth shape must be one word, got {text!r}")
    return shape


# ------------------------------------------------------------------------------ Rhubarb


def read_rhubarb_tsv(path: str | Path) -> Cues:
    """Rhubarb's TSV: ``time<TAB>shape`` per line (blank lines skipped)."""
    _, lines = text_lines(path)
    cues: list[Cue] = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 2:
            raise FormatError(path, f"line {i}", f"expected 'time<TAB>shape', got {line[:60]!r}")
        where = f"line {i}"
        cues.append(
            Cue(seconds(path, where, parts[0], "time"), shape_word(path, where, parts[1]), where)
        )
    in_order(path, cues)
    return Cues(str(path), tuple(cues), "rhubarb")


def _rhubarb_cue(
    path: str | Path, where: str, start: str, end: str, shape: object, before: float | None
) -> tuple[Cue, float]:
    t0 = seconds(path, where, start, "start")
    t1 = seconds(path, where, end, "end")
    if t1 < t0:
        raise FormatError(path, where, f"end {t1:g} s is before start {t0:g} s")
    if before is not None and t0 != before:
        raise FormatError(
            path,
            where,
            f"starts at {t0:g} s, the cue before ends at {before:g} s: Rhubarb's "
            "cues follow one another without gap or overlap",
        )
    return Cue(
        t0, shape_word(path, where, shape if isinstance(shape, str) else repr(shape)), where
    ), t1


def read_rhubarb_json(path: str | Path) -> Cues:
    """Rhubarb's JSON: ``mouthCues`` of ``{"start", "end", "value"}``, back to back."""
    text, _ = text_lines(path)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"line {exc.lineno}", f"not JSON: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:
        raise FormatError(path, "", f"not usable JSON: {str(exc)[:80]}") from None
    cues_in = doc.get("mouthCues") if isinstance(doc, dict) else None
    if not isinstance(cues_in, list):
        raise FormatError(path, "", 'not Rhubarb JSON: no "mouthCues" list')
    cues: list[Cue] = []
    end: float | None = None
    for i, item in enumerate(cues_in):
        where = f"mouthCues[{i}]"
        if not isinstance(item, dict) or not {"start", "end", "value"} <= item.keys():
            raise FormatError(path, where, 'a cue is {"start": s, "end": s, "value": shape}')
        times = []
        for key in ("start", "end"):
            v = item[key]
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise FormatError(path, where, f"{key} must be a number of seconds, got {v!r}")
            times.append(repr(v))
        cue, end = _rhubarb_cue(path, where, times[0], times[1], item["value"], end)
        cues.append(cue)
    return Cues(str(path), tuple(cues), "rhubarb", end)


def read_rhubarb_xml(path: str | Path) -> Cues:
    """Rhubarb's XML: ``<mouthCue start="s" end="s">shape</mouthCue>`` elements. A DTD is
    refused (Rhubarb writes none; it is how entity bombs arrive)."""
    text, _ = text_lines(path)
    parser = expat.ParserCreate()
    cues: list[Cue] = []
    state: dict[str, Any] = {"open": None, "end": None, "root": None}

    def line() -> str:
        return f"line {parser.CurrentLineNumber}"

    def doctype(*_args: object) -> None:
        raise FormatError(path, line(), "a DTD (<!DOCTYPE ...>): Rhubarb XML has none")

    def start(name: str, attrs: dict[str, str]) -> None:
        if state["root"] is None:
            state["root"] = name
            if name != "rhubarbResult":
                raise FormatError(
                    path, line(), f"not Rhubarb XML: root <{name}>, not <rhubarbResult>"
                )
        if state["open"] is not None:
            raise FormatError(path, line(), f"<{name}> inside a <mouthCue>")
        if name == "mouthCue":
            if "start" not in attrs or "end" not in attrs:
                raise FormatError(path, line(), '<mouthCue> needs start="s" and end="s"')
            state["open"] = (line(), attrs["start"], attrs["end"], [])

    def chars(data: str) -> None:
        if state["open"] is not None:
            state["open"][3].append(data)

    def end(name: str) -> None:
        if name == "mouthCue" and state["open"] is not None:
            where, t0, t1, text_parts = state["open"]
            cue, state["end"] = _rhubarb_cue(path, where, t0, t1, "".join(text_parts), state["end"])
            cues.append(cue)
            state["open"] = None

    parser.StartDoctypeDeclHandler = doctype
    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        raise FormatError(
            path, f"line {exc.lineno}", f"not XML: {expat.errors.messages[exc.code]}"
        ) from None
    except RecursionError:
        raise FormatError(path, line(), "XML nested too deep") from None
    if not cues:
        raise FormatError(path, "", "no <mouthCue> elements")
    return Cues(str(path), tuple(cues), "rhubarb", state["end"])
