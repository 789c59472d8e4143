"""Bottango exports (generated code, SD-card files, JSON) as tracks in joint radians.

The rig's use is one call per joint::

    export = read_export("GeneratedCodeAnimations.cpp")      # or an SD card dir, or .json
    track = export.track(0, "0", signal=UnitMap((1000, 2000), (0, 40), "us"))

* :func:`read_export` takes the form from the path (or ``form=``) and returns a
  :class:`BottangoExport`. The three forms give identical tracks; :mod:`.bottango_forms` finds
  the command lines and this module reads them.
* :class:`BottangoExport` holds ``effectors`` (their registrations), ``animations`` (segments
  per effector) and ``info`` (commands skipped, folding curves).
* :meth:`BottangoExport.track` gives a :class:`~.bottango_curve.BezierTrack`. Exactly one of
  ``signal=`` (the registered signal, e.g. µs, to degrees) or ``movement=`` (0..1 to degrees).
* With a registration the track is what the driver does (:mod:`.bottango_slew`): the start
  signal until the first curve, then the curves at most the registered speed limit fast.

Commands that move no joint (colour, on/off, audio, ...) are skipped and counted; an unknown
command is a FormatError naming its line. The commands read and their units:
``docs/targets.md`` (Bottango exports).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

from hilsim.targets.formats.bottango_curve import Y_MAX, BezierSegment, BezierTrack
from hilsim.targets.formats.bottango_forms import Line, RawExport, read_code, read_json, read_sd
from hilsim.targets.formats.bottango_slew import driver_terms, driver_track
from hilsim.targets.formats.common import FormatError, UnitMap
from hilsim.targets.tracks import Track

__all__ = [
    "Animation", "BezierSegment", "BezierTrack", "BottangoExport", "Effector",
    "PlaybackConfig", "read_export",
]  # fmt: skip

FORMS = ("code", "sd", "json")

#: commands that move no joint: skipped and counted (what they are, for the info list)
SKIPPED = {
    "sCO": "on/off events", "sCT": "trigger events", "sCC": "colour curves",
    "sCCI": "instant colours", "rECOnOff": "on/off event registrations",
    "rECTrig": "trigger event registrations", "rECColor": "colour registrations",
    "rAud": "audio registrations", "rCtrl": "relay controllers", "xCtrl": "relay clean-ups",
    "xUCtrl": "relay clean-ups", "sCfg": "driver settings", "sycM": "stepper syncs",
}  # fmt: skip
_TIMED = frozenset({"sC", "sCO", "sCT", "sCC"})
_INT = re.compile(r"[+-]?\d{1,10}")
_INTS = re.compile(r"[+-]?\d{1,10}(,[+-]?\d{1,10})*")
_FLOAT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


@dataclass(frozen=True)
class Effector:
    """A registered effector. ``signal_min``/``signal_max`` (None for a curved event, which
    has only a movement) in ``unit``; ``start`` is its start signal (a curved event: start
    movement 0..1). ``address``/``pin`` as the registration gives them (None if it has none)."""

    identifier: str
    kind: str
    signal_min: float | None
    signal_max: float | None
    start: float
    unit: str
    where: str
    address: int | None = None
    pin: int | None = None
    max_per_s: float | None = None


@dataclass(frozen=True)
class PlaybackConfig:
    """An animation's 8 playback numbers, in the export's order."""

    play_on_start: int
    loop_on_start: int
    idle: int
    play_on_pin: int
    loop: int
    pin_mode: int  # 0 LOW, 1 HIGH, 2 analog range
    ladder_min: int
    ladder_max: int

    def describe(self) -> str:
        """e.g. ``"trigger on input 10, rising (HIGH), no loop"``."""
        parts = []
        if self.play_on_start:
            parts.append("plays on start" + (", looping" if self.loop_on_start else ""))
        if self.idle:
            parts.append("idle animation (plays, looping, when nothing else does)")
        if self.play_on_pin > 0:
            how = {0: "falling (LOW)", 1: "rising (HIGH)"}.get(
                self.pin_mode, f"analog value in {self.ladder_min}-{self.ladder_max}"
            )
            parts.append(f"trigger on input {self.play_on_pin}, {how}")
        if not parts:
            parts.append("not started by the export's playback logic (no start, idle or trigger)")
        parts.append("loop" if self.loop else "no loop")
        return ", ".join(parts)


@dataclass(frozen=True)
class Animation:
    index: int
    name: str
    config: PlaybackConfig | None
    segments: dict[str, tuple[BezierSegment, ...]]
    loop_segments: dict[str, tuple[BezierSegment, ...]]

    def describe(self) -> str:
        title = f"animation {self.index}" + (f' "{self.name}"' if self.name else "")
        cfg = self.config.describe() if self.config else "no playback config"
        return f"{title}: {cfg}; effectors {', '.join(sorted(self.segments)) or 'none'}"


@dataclass(frozen=True)
class BottangoExport:
    path: str
    form: str
    effectors: dict[str, Effector]
    animations: dict[int, Animation]
    info: tuple[str, ...] = ()

    def animation(self, key: int | str) -> Animation:
        """By index, or by name (from the generated code's comments or the JSON)."""
        for anim in self.animations.values():
            if key == anim.index or (isinstance(key, str) and key and key == anim.name):
                return anim
        have = ", ".join(a.describe().split(":")[0] for a in self.animations.values())
        raise FormatError(self.path, "", f"no animation {key!r}; the export has {have or 'none'}")

    def track(
        self,
        animation: int | str,
        effector: str,
        *,
        signal: UnitMap | None = None,
        movement: UnitMap | None = None,
        loop: bool = False,
    ) -> Track:
        """One effector's curve in one animation in joint radians, as the driver plays it
        (``loop=True``: its loop data, from its first curve's start, not the start signal);
        ``signal`` maps the signal to degrees, ``movement`` 0..1 to degrees (exactly one)."""
        anim = self.animation(animation)
        table = anim.loop_segments if loop else anim.segments
        eid = str(effector)
        if eid not in table:
            raise FormatError(
                self.path,
                "",
                f"animation {anim.index} has no {'loop ' if loop else ''}curve "
                f"for effector {eid!r}; it has curves for {', '.join(sorted(table)) or 'none'}",
            )
        if (signal is None) == (movement is None):
            raise ValueError(
                "give signal= (the effector's signal, e.g. µs, to degrees) or movement= "
                "(Bottango's movement 0..1 to degrees), exactly one"
            )
        umap: UnitMap | None
        if signal is not None:
            eff = self.effectors.get(eid)
            if eff is None or eff.signal_min is None or eff.signal_max is None:
                raise FormatError(
                    self.path,
                    "",
                    f"effector {eid!r} has no signal range in the setup "
                    "(no rSVPin/rSVI2C/rMTR/rSTPin/rSTDir registration): map its movement "
                    "0..1 to degrees instead (movement=UnitMap((0, 1), (deg0, deg1)))",
                )
            lo, hi, umap = eff.signal_min, eff.signal_max, signal
        else:
            lo, hi, umap = 0.0, 1.0, movement
        assert umap is not None
        k = math.radians(umap.deg_per_unit)
        offset = math.radians(umap.degrees[0]) + k * (lo - umap.source[0])
        src = f"{self.path} animation {anim.index} effector {eid}"
        eff = self.effectors.get(eid)
        start, rate = driver_terms(eff)
        curve = BezierTrack(table[eid], offset, k * (hi - lo) / Y_MAX, src, None if loop else start)
        limit = f"{eff.max_per_s:g} {eff.unit}/s" if eff is not None else ""
        return driver_track(curve, rate, limit)


def read_export(path: str | Path, form: str | None = None) -> BottangoExport:
    """Read a Bottango export in any of its three forms (see the module docstring)."""
    p = Path(path)
    if form is None:
        form = "sd" if p.is_dir() else "json" if p.suffix.lower() == ".json" else "code"
    if form not in FORMS:
        raise ValueError(f"form must be one of {', '.join(FORMS)}, got {form!r}")
    if form != "sd" and not p.is_file():
        raise FormatError(p, "", "no such file" if not p.exists() else "not a file")
    raw = {"code": read_code, "sd": read_sd, "json": read_json}[form](p)
    return _interpret(raw)


# ------------------------------------------------------------------------------ the commands
@dataclass
class _State:
    effectors: dict[str, Effector]
    skipped: dict[str, list[Any]]  # name -> [how many, the first one's Line]
    folds: list[str]
    segments: dict[str, list[BezierSegment]] = field(default_factory=dict)
    lines: dict[int, Line] = field(default_factory=dict)  # id(segment) -> its command
    sync_ms: int = 0
    last_timed_ms: int = 0


def _ints(line: Line, fields: list[str], names: str) -> list[int]:
    if _INTS.fullmatch(",".join(fields)):  # the usual case, in one match
        return [int(v) for v in fields]
    out = []
    for value, name in zip(fields, names.split(), strict=True):
        if not _INT.fullmatch(value.strip()):
            raise line.error(f"{name} must be an integer, got {value.strip()[:20]!r}")
        out.append(int(value))
    return out


def _num(line: Line, value: str, name: str) -> float:
    if not _FLOAT.fullmatch(value.strip()) or not math.isfinite(float(value)):
        raise line.error(f"{name} must be a finite number, got {value.strip()[:20]!r}")
    return float(value)


_SHAPES = {  # name -> the fields after the command name
    "sC": "id startMs durationMs startY startControlX startControlY endY endControlX endControlY",
    "sCI": "id targetY",
    "rSVPin": "pin min max maxPerSec start",
    "rSVI2C": "address pin min max maxPerSec start",
    "rMTR": "id min max maxPerSec start",
    "rSTPin": "pin0 pin1 pin2 pin3 maxCCW maxCW maxPerSec start",
    "rSTDir": "stepPin dirPin clockwiseLow maxCCW maxCW maxPerSec start",
    "rECC": "id maxPerSec startMovement pin",
    "upE": "id min max maxPerSec",
    "xE": "", "xC": "", "xUE": "id", "xUC": "id", "tSYN": "ms",
}  # fmt: skip


_SC_FIELDS = _SHAPES["sC"].partition(" ")[2]


def _register(st: _State, line: Line, name: str, f: list[str], pre: str) -> None:
    speed: float  # whole numbers in a registration, but a curved event's are not
    start: float
    if name == "rSVPin":
        pin, lo, hi, speed, start = _ints(line, f, _SHAPES[name])
        eff = Effector(
            f"{pre}{pin}", "pin servo", lo, hi, start, "us", line.where, None, pin, speed
        )
    elif name == "rSVI2C":
        addr, pin, lo, hi, speed, start = _ints(line, f, _SHAPES[name])
        eff = Effector(
            f"{pre}{addr}{pin}", "I2C servo", lo, hi, start, "us", line.where, addr, pin, speed
        )
    elif name == "rMTR":
        lo, hi, speed, start = _ints(line, f[1:], "min max maxPerSec start")
        eff = Effector(pre + f[0].strip(), "custom motor", lo, hi, start, "signal", line.where,
                       max_per_s=speed)  # fmt: skip
    elif name in ("rSTPin", "rSTDir"):
        vals = _ints(line, f, _SHAPES[name])
        ccw, cw, speed, start = vals[-4:]
        eff = Effector(f"{pre}{vals[0]}", "stepper", ccw, cw, start, "steps", line.where,
                       None, vals[0], speed)  # fmt: skip
    else:  # rECC
        speed, start = _num(line, f[1], "maxPerSec"), _num(line, f[2], "startMovement")
        (pin,) = _ints(line, f[3:], "pin")
        eff = Effector(pre + f[0].strip(), "curved event", None, None, start, "movement",
                       line.where, None, pin, speed)  # fmt: skip
    if not eff.identifier or eff.identifier == pre:
        raise line.error("the effector identifier is empty")
    st.effectors[eff.identifier] = eff


def _curve(st: _State, line: Line, name: str, f: list[str], pre: str) -> None:
    eid = pre + f[0].strip()
    if not f[0].strip():
        raise line.error("the effector identifier is empty")
    if name == "sCI":
        (y,) = _ints(line, f[1:], "targetY")
        _check_y(line, y, "targetY")
        seg = BezierSegment.instant(st.last_timed_ms, y, line.where)
    else:
        start, dur, y0, c1x, c1y, y1, c2x, c2y = _ints(line, f[1:], _SC_FIELDS)
        if dur < 0:
            raise line.error(f"durationMs must be >= 0, got {dur}")
        start += st.sync_ms
        if start < 0:
            raise line.error(f"the curve starts at {start} ms, before the animation")
        _check_y(line, y0, "startY")
        _check_y(line, y1, "endY")
        seg = BezierSegment.from_command(start, dur, y0, c1x, c1y, y1, c2x, c2y, line.where)
        st.last_timed_ms = start
        if not seg.monotone:
            st.folds.append(
                f"{line.path}:{line.where}: effector {eid}'s curve at {start} ms runs back in "
                "time (a handle reaches outside the segment); followed forward, it jumps "
                "where it folds"
            )
    st.segments.setdefault(eid, []).append(seg)
    st.lines[id(seg)] = line


def _check_y(line: Line, y: int, name: str) -> None:
    if not 0 <= y <= Y_MAX:
        raise line.error(f"{name} must be in 0..8192 (Bottango's movement), got {y}")


def _command(st: _State, line: Line, text: str, pre: str = "", depth: int = 0) -> None:
    if depth > 4:
        raise line.error("sSY/sR nested more than 4 deep")
    if (m := re.fullmatch(r"(.*),h(\d+)", text)) is not None:
        body, want = m.group(1), int(m.group(2))
        if sum(map(ord, body)) != want:
            raise line.error(f"hash h{want} does not match the command (sum {sum(map(ord, body))})")
        text = body
    name, _, rest = text.partition(",")
    name = name.strip()
    if name == "sR":
        relay, _, inner = rest.partition(",")
        (k,) = _ints(line, [relay], "relay")
        return _command(st, line, inner, f"{pre}{k}/", depth + 1)
    if name == "sSY":
        return _sync(st, line, rest, pre, depth + 1)
    if name in SKIPPED:
        st.skipped.setdefault(name, [0, line])[0] += 1
        if name in _TIMED:  # its time still places a later sCI
            fields = rest.split(",")
            if len(fields) < 2:
                raise line.error(f"{name} needs an identifier and a startMs")
            (start,) = _ints(line, fields[1:2], "startMs")
            st.last_timed_ms = st.sync_ms + start
        return None
    if name not in _SHAPES:
        raise line.error(
            f"unknown command {name[:12]!r} (known: {', '.join(sorted(_SHAPES))}, "
            f"sSY, sR; skipped: {', '.join(sorted(SKIPPED))})"
        )
    f = rest.split(",") if rest else []
    want = len(_SHAPES[name].split())
    if len(f) != want:
        raise line.error(f"{name} takes {want} fields ({_SHAPES[name] or 'none'}), got {len(f)}")
    run = _register if name[0] == "r" else _curve if name in ("sC", "sCI") else _housekeeping
    run(st, line, name, f, pre)
    return None


def _housekeeping(st: _State, line: Line, name: str, f: list[str], pre: str) -> None:
    if name == "tSYN":
        (st.sync_ms,) = _ints(line, f, "ms")
        return
    ids = [pre + f[0].strip()] if f else None
    if name in ("xE", "xUE"):
        for eid in ids or [e for e in st.effectors if e.startswith(pre)]:
            st.effectors.pop(eid, None)
    elif name in ("xC", "xUC"):
        if any(st.segments.get(e) for e in (ids or st.segments)):
            raise line.error("clearing curves inside an animation is not supported")
    else:  # upE
        lo, hi, speed = _ints(line, f[1:], "min max maxPerSec")
        eff = st.effectors.get(ids[0]) if ids else None
        if eff is None or eff.signal_min is None:
            raise line.error(f"upE for {f[0].strip()[:20]!r}, which has no signal range registered")
        st.effectors[eff.identifier] = Effector(
            eff.identifier,
            eff.kind,
            lo,
            hi,
            eff.start,
            eff.unit,
            line.where,
            eff.address,
            eff.pin,
            speed,
        )


def _sync(st: _State, line: Line, rest: str, pre: str, depth: int) -> None:
    """``sSY,<cmd>,<args>;<args>;*<cmd2>,<args>;...``: each chunk gets the current prefix
    (``<cmd>,``) unless it starts with it; ``*<cmd>,`` changes the prefix."""
    prefix, _, body = rest.partition(",")
    prefix += ","
    for chunk in body.split(";"):
        chunk = chunk.strip()
        if not chunk:
            continue
        if chunk.startswith("*"):
            head, _, chunk = chunk[1:].partition(",")
            prefix = head + ","
        _command(st, line, chunk if chunk.startswith(prefix) else prefix + chunk, pre, depth)


def _run(st: _State, lines: list[Line], setup: bool) -> dict[str, tuple[BezierSegment, ...]]:
    st.segments, st.sync_ms, st.last_timed_ms = {}, 0, 0
    for line in lines:
        _command(st, line, line.text)
    out = {}
    for eid, segs in st.segments.items():
        order = sorted(segs, key=lambda s: (s.start_ms, s.dur_ms))
        for a, b in pairwise(order):
            if b.start_ms < a.end_ms:
                raise st.lines[id(b)].error(
                    f"effector {eid}'s curve at {b.start_ms:g}-{b.end_ms:g} ms overlaps the one "
                    f"at {a.start_ms:g}-{a.end_ms:g} ms ({a.where}); curves on one effector "
                    "must not overlap"
                )
        out[eid] = tuple(order)
    if setup and out:
        raise st.lines[id(next(iter(out.values()))[0])].error("a curve in the setup data")
    st.lines.clear()
    return out


def _interpret(raw: RawExport) -> BottangoExport:
    st = _State({}, {}, [])
    _run(st, raw.setup, True)
    anims = {}
    for idx in sorted(raw.animations):
        ra = raw.animations[idx]
        data, loop = _run(st, ra.data, False), _run(st, ra.loop, False)
        config = None
        if ra.config is not None:
            config = PlaybackConfig(*ra.config)
            if config.pin_mode > 2:
                raise FormatError(
                    *ra.config_at,
                    f"playOnPinHigh is {config.pin_mode}; allowed 0 (low), "
                    "1 (high), 2 (analog range)",
                )
        anims[idx] = Animation(idx, ra.name, config, data, loop)
    info = [
        f"skipped {n} {name} command{'s' if n > 1 else ''} ({SKIPPED[name]}; first at "
        f"{first.path}:{first.where})"
        for name, (n, first) in sorted(st.skipped.items())
    ]
    return BottangoExport(raw.path, raw.form, dict(st.effectors), anims, tuple(info + st.folds))
