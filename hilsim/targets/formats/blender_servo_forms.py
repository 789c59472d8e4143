"""The three forms of a blender-servo-animation export, read into position records.

``.json``, ``.bin`` and ``.h`` each become ``(frames, frame_of, servo, position)``: the number of
frames and, per position the file lists, its frame, servo ID and position (int64 arrays, in file
order). :mod:`hilsim.targets.formats.blender_servo` (the public reader) turns them into tracks;
the layouts are described there. Every bad input is one FormatError naming file and position.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn, TypeGuard

import numpy as np

from hilsim._types import IntArray
from hilsim.targets.formats.common import FormatError, decode_text

REC_START, REC_END, FRAME_END, REC_LEN = 0x3C, 0x3E, 0x0A, 5
#: (frames, frame_of, servo, position): what every form is read into
Records = tuple[int, IntArray, IntArray, IntArray]
#: names a place in the file by its byte offset (``"line 3 (array byte 7)"``)
Where = Callable[[int], str]
MAX_POSITION = 0xFFFF  # a position is a big-endian u16 in .bin and .h
MAX_SERVO_ID = 0xFF
NL, NUL = b"\n", b"\0"


def parse_json(data: bytes, path: str | Path) -> tuple[int, Records, str]:
    text = _text(data, path)

    def no_constant(name: str) -> NoReturn:
        raise ValueError(f"{name} is not a JSON number")

    try:
        doc = json.loads(text, parse_constant=no_constant)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"line {exc.lineno}", f"not JSON: {exc.msg}") from None
    except ValueError as exc:
        raise FormatError(path, "", f"not JSON: {exc}") from None
    except RecursionError:
        raise FormatError(path, "", "not JSON: nested too deeply") from None
    if not isinstance(doc, dict) or "positions" not in doc:
        raise FormatError(path, "", "not a blender-servo-animation export: no top-level "
                          "'positions' list")  # fmt: skip
    fps = doc.get("fps")
    if not is_int(fps) or fps < 1:
        raise FormatError(path, "fps", f"must be a whole number ≥ 1, got {_short(fps)}")
    positions = doc["positions"]
    if not isinstance(positions, list):
        raise FormatError(path, "positions", f"must be a list of frames, got {_kind(positions)}")
    n_frames = doc.get("frames", len(positions))
    if not is_int(n_frames) or n_frames != len(positions):
        raise FormatError(path, "frames", f"says {_short(n_frames)} but 'positions' holds "
                          f"{len(positions)} frames")  # fmt: skip
    ids: dict[str, int] = {}  # keys already checked
    frame_of, servo, position = [], [], []
    for k, entry in enumerate(positions):
        if not isinstance(entry, dict):
            raise FormatError(path, f"frame {k}", "must be an object of servo ID -> position, "
                              f"got {_kind(entry)}")  # fmt: skip
        for key, value in entry.items():
            if key not in ids:
                if not re.fullmatch(r"[0-9]{1,3}", key) or int(key) > MAX_SERVO_ID:
                    raise FormatError(path, f"frame {k}", f"servo ID {_short(key)} is not 0-255")
                ids[key] = int(key)
            if not is_int(value) or not 0 <= value <= MAX_POSITION:
                raise FormatError(path, f"frame {k}", f"servo {key}: position {_short(value)} is "
                                  "not an integer 0-65535")  # fmt: skip
            frame_of.append(k)
            servo.append(ids[key])
            position.append(value)
    frame_arr, servo_arr, position_arr = (
        np.array(x, dtype=np.int64) for x in (frame_of, servo, position)
    )
    recs = (len(positions), frame_arr, servo_arr, position_arr)
    scene = doc.get("scene")
    return fps, recs, scene if isinstance(scene, str) else ""


_FRAME = re.compile(rb"(?:\x3c[\x00-\xff]{3}\x3e)*\x0a")


def records(data: bytes, path: str | Path, where: Where | None = None) -> Records:
    """``3C id hi lo 3E`` records and ``0A`` frame ends -> (frames, frame_of, servo,
    position): a frame at a time by regex, the records by numpy, and where the regex stops,
    :func:`bad_byte` names the byte. ``where(i)`` names byte ``i`` (default ``byte i``)."""
    where = where or (lambda i: f"byte {i}")
    ends: list[int] = []
    pos, n = 0, len(data)
    while pos < n:
        m = _FRAME.match(data, pos)
        if m is None:
            raise bad_byte(data, pos, len(ends), path, where)
        pos = m.end()
        ends.append(pos - 1)
    arr = np.frombuffer(data, np.uint8)
    keep = np.ones(n, bool)
    keep[ends] = False
    rec = arr[keep].reshape(-1, REC_LEN).astype(np.int64)
    counts = (np.diff(np.array([-1, *ends])) - 1) // REC_LEN
    frame_of = np.repeat(np.arange(len(ends), dtype=np.int64), counts)
    return len(ends), frame_of, rec[:, 1], rec[:, 2] * 256 + rec[:, 3]


def bad_byte(data: bytes, i: int, frame: int, path: str | Path, where: Where) -> FormatError:
    """The error at the first byte from ``i`` (the start of frame ``frame``) that breaks the
    record layout."""
    n, records_in_frame = len(data), False
    while i < n:
        if data[i] == FRAME_END:
            i, frame, records_in_frame = i + 1, frame + 1, False
        elif data[i] != REC_START:
            return FormatError(path, where(i), f"0x{data[i]:02x} where a record (0x3c '<') or a "
                               f"frame end (0x0a) must start (frame {frame})")  # fmt: skip
        elif i + REC_LEN > n:
            return FormatError(path, where(i), f"truncated: a record starts here but only "
                               f"{n - i} of its 5 bytes follow (frame {frame})")  # fmt: skip
        elif data[i + 4] != REC_END:
            return FormatError(path, where(i + 4), f"0x{data[i + 4]:02x} where a record ends "
                               f"with 0x3e '>' (record <id hi lo> of frame {frame} starts at "
                               f"{where(i)})")  # fmt: skip
        else:
            i, records_in_frame = i + REC_LEN, True
    if records_in_frame:
        return FormatError(path, where(n), f"truncated: frame {frame} has positions but no "
                           "frame end 0x0a")  # fmt: skip
    return FormatError(path, where(i), "not a frame of records")  # not reached: a guard


# an unclosed /* runs to the end (one match, not a rescan per "/*": linear on any input)
_C_COMMENT = re.compile(rb"/\*.*?(?:\*/|\Z)|//[^\n]*", re.S)
_CONST = re.compile(
    rb"\bconst\s+(?:byte|int|unsigned\s+int|uint8_t|uint16_t)\s+(FPS|FRAMES|LENGTH)"
    rb"\s*=\s*([0-9]{1,9})\s*;"
)
_ARRAY = re.compile(rb"\bANIMATION_DATA\s*\[\s*(LENGTH|[0-9]{1,9})\s*\]\s*=\s*\{([^{}]*)\}\s*;")
_TOKEN = re.compile(rb"\s*(0[xX][0-9a-fA-F]{1,8}|[0-9]{1,9})\s*")
_NUMBER = re.compile(rb"0[xX][0-9a-fA-F]+|[0-9]+")
_WHITESPACE = np.frombuffer(b" \t\r\n\v\f", np.uint8)


def parse_h(data: bytes, path: str | Path) -> tuple[int, Records, str]:
    _text(data, path)
    # comments blanked (newlines kept), so offsets and line numbers stay the file's own
    src = _C_COMMENT.sub(lambda m: re.sub(rb"[^\n]", b" ", m.group()), data)

    def line(offset: int) -> str:
        return f"line {data.count(NL, 0, offset) + 1}"

    consts: dict[str, int] = {}
    for m in _CONST.finditer(src):
        name = m.group(1).decode()
        if name in consts:
            raise FormatError(path, line(m.start()), f"{name} is defined twice")
        consts[name] = int(m.group(2))
    for name in ("FPS", "FRAMES", "LENGTH"):
        if name not in consts:
            raise FormatError(path, "", f"no 'const ... {name} = N;': not a "
                              "blender-servo-animation header")  # fmt: skip
    arrays = list(_ARRAY.finditer(src))
    if len(arrays) != 1:
        what = "no" if not arrays else f"{len(arrays)}"
        raise FormatError(path, "", f"{what} 'ANIMATION_DATA[LENGTH] = {{...}};' arrays (need one)")
    body, base = arrays[0].group(2), arrays[0].start(2)
    values = _hex_bytes(body)
    if values is None:  # not the add-on's own "0xNN, 0xNN, ...": token by token
        values = tokens(body, base, path, line)
    if consts["LENGTH"] != len(values):
        raise FormatError(path, line(base), f"LENGTH is {consts['LENGTH']} but the array "
                          f"holds {len(values)} bytes")  # fmt: skip

    def at(i: int) -> str:
        offsets = [base + m.start() for m in _NUMBER.finditer(body)]
        return f"{line(offsets[i])} (array byte {i})" if i < len(offsets) else "array end"

    recs = records(values, path, at)
    frames = recs[0]
    if consts["FRAMES"] != frames:
        raise FormatError(path, "", f"FRAMES is {consts['FRAMES']} but the array holds "
                          f"{frames} frames")  # fmt: skip
    if consts["FPS"] < 1:
        raise FormatError(path, "", "FPS is 0")
    ns = re.search(rb"\bnamespace\s+([A-Za-z_][A-Za-z0-9_]*)\s*\{", src)
    return consts["FPS"], recs, ns.group(1).decode() if ns else ""


_HEX = np.full(256, -1, np.int64)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX[_c] = _HEX[bytes([_c]).upper()[0]] = _i


def _hex_bytes(body: bytes) -> bytes | None:
    """``0xNN, 0xNN, ...`` (any whitespace, a trailing comma) as bytes, at numpy's speed; None
    for anything else."""
    raw = np.frombuffer(body, np.uint8)
    solid = np.flatnonzero(~np.isin(raw, _WHITESPACE))
    gap = np.diff(solid) > 1  # whitespace between two characters: one must be a comma
    if np.any((raw[solid[:-1][gap]] != 0x2C) & (raw[solid[1:][gap]] != 0x2C)):
        return None  # "0x3 c": not a C array; the token reader names it
    flat = body.translate(None, b" \t\r\n\v\f").removesuffix(b",") + b","
    if len(flat) % 5 or len(flat) < 5:
        return None
    a = np.frombuffer(flat, np.uint8).reshape(-1, 5)
    hi, lo = _HEX[a[:, 2]], _HEX[a[:, 3]]
    ok = (a[:, 0] == 0x30) & ((a[:, 1] | 0x20) == 0x78) & (a[:, 4] == 0x2C) & (hi >= 0) & (lo >= 0)
    return (hi * 16 + lo).astype(np.uint8).tobytes() if ok.all() else None


def tokens(body: bytes, base: int, path: str | Path, line: Where) -> bytes:
    """The array's bytes, token by token (hex or decimal), naming the line of a bad one."""
    values: list[int] = []
    parts = body.split(b",")
    pos = base
    for j, part in enumerate(parts):
        if j == len(parts) - 1 and not part.strip():
            break  # the trailing comma the add-on writes
        m = _TOKEN.fullmatch(part)
        if m is None:
            token = part.strip()[:20].decode(errors="replace")
            raise FormatError(path, line(pos + len(part) - len(part.lstrip())),
                              f"{token!r} is not a byte (0x00-0xff)")  # fmt: skip
        value = int(m.group(1), 0)
        if value > 0xFF:
            raise FormatError(path, line(pos + m.start(1)), f"{m.group(1).decode()} is not a byte")
        values.append(value)
        pos += len(part) + 1
    return bytes(values)


# ------------------------------------------------------------ what the Arduino library misreads
#: the bytes the add-on's Arduino library (BlenderServoAnimation 2.0.0) takes for markers
#: wherever they stand: ``ServoManager::parseData`` stops a frame at any 0x0A, and
#: ``Command::write`` restarts its 5-byte command at any 0x3C
MARKERS = {FRAME_END: "a frame end", REC_START: "a record start"}
_FIELDS = ("its ID", "its position's high byte", "its position's low byte")


def arduino_misread(servo: np.ndarray, position: np.ndarray) -> tuple[int, int, str] | None:
    """The records whose ID or position byte is a marker byte (:data:`MARKERS`) -> (how many,
    the first one's index, ``"its ID is 0x0a, ... as a frame end"``); None when none is."""
    fields = np.stack([servo, position >> 8, position & 0xFF], axis=1)
    hit = np.isin(fields, list(MARKERS))
    rows = np.flatnonzero(hit.any(axis=1))
    if not rows.size:
        return None
    r = int(rows[0])
    k = int(np.argmax(hit[r]))
    value = int(fields[r, k])
    return (
        int(rows.size),
        r,
        (
            f"{_FIELDS[k]} is 0x{value:02x}, which the add-on's Arduino library (2.0.0) reads as "
            f"{MARKERS[value]} wherever it stands"
        ),
    )


# --------------------------------------------------------------------------------- helpers


def _text(data: bytes, path: str | Path) -> str:
    return decode_text(data, path, "a NUL byte: binary, not text")


def is_int(x: object) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def is_number(x: object) -> TypeGuard[float]:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


_KINDS: dict[type, str] = {dict: "an object", list: "a list", str: "a string"}


def _kind(x: object) -> str:
    return _KINDS.get(type(x), _short(x))


def _short(x: object) -> str:
    text = repr(x)
    return text if len(text) <= 40 else text[:37] + "..."
